#!/usr/bin/env python3
"""The commands shown in a Markdown document, for docs_run.sh.

usage: docs_cmds.py DOC.md DIR

Reads the indented (4 spaces) and fenced code blocks of DOC.md and prints, one
a line, each line of a block that is a command or a synopsis, as
"K<TAB>LINE<TAB>command|synopsis<TAB>TEXT" (K counts from 1); a command's
shown output goes to DIR/want.K (an empty file when none is shown).

A command is a line `$ vox ...` / `$ voxd ...` (its shown output: the lines
under it up to the next `$` line or the end of the block; none: null), or a
line `build/release/vox ...` / `build/release/voxd ...` (no shown output).
A line `vox ...` without the prompt is the grammar of a command (a synopsis:
metavariables in capitals, [ ], |), not a command to run.
"""
import re, sys

PROMPT = re.compile(r"^\$ ((build/release/)?voxd? .*)$")
BARE = re.compile(r"^(build/release/voxd? .*)$")
SYNOPSIS = re.compile(r"^(voxd? (?![0-9:]).*)$")


def blocks(lines):
    """(first line number, [lines]) of each code block, indent removed."""
    i, n = 0, len(lines)
    while i < n:
        if lines[i].startswith("```"):
            j = i + 1
            while j < n and not lines[j].startswith("```"):
                j += 1
            yield i + 2, lines[i + 1:j]
            i = j + 1
        elif lines[i].startswith("    ") and (i == 0 or not lines[i - 1].strip()):
            j = i
            while j < n and (lines[j].startswith("    ") or
                             (not lines[j].strip() and j + 1 < n and lines[j + 1].startswith("    "))):
                j += 1
            yield i + 1, [l[4:] for l in lines[i:j]]
            i = j
        else:
            i += 1


def emit(d, item):
    emit.k += 1
    with open("%s/want.%d" % (d, emit.k), "w", encoding="utf-8") as f:
        f.write("".join(l + "\n" for l in item.get("output") or []))
    print("%d\t%d\t%s\t%s" % (emit.k, item["line"], item["kind"], item["cmd"]))


emit.k = 0


def main(path, d):
    lines = open(path, encoding="utf-8").read().split("\n")
    for first, body in blocks(lines):
        k = 0
        while k < len(body):
            line = body[k].rstrip()
            m = PROMPT.match(line)
            if m:
                out = []
                k += 1
                while k < len(body) and not PROMPT.match(body[k].rstrip()):
                    out.append(body[k].rstrip())
                    k += 1
                while out and not out[-1]:
                    out.pop()
                emit(d, {"line": first + k - len(out) - 1, "kind": "command",
                         "cmd": m.group(1), "output": out})
                continue
            if BARE.match(line):
                emit(d, {"line": first + k, "kind": "command", "cmd": line})
            elif SYNOPSIS.match(line):
                emit(d, {"line": first + k, "kind": "synopsis", "cmd": line})
            k += 1


main(sys.argv[1], sys.argv[2])

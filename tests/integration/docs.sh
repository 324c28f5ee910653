#!/bin/bash
# The documentation against the programs, for what can rot: the README's two
# commands, no path out of the repository, every long option of the --help
# texts in the manual pages and in docs/ (and every option the manual pages
# name in a --help), every file path and link the docs name, the layering
# table against the Makefile, the configuration keys and their stated
# defaults, manual pages that render without a warning, and `make install`
# into a temporary root: the files, the unit's paths, and the installed voxd
# serving with the installed configuration; then `make uninstall`.
. "$(dirname "${BASH_SOURCE[0]}")/daemon_lib.bash"

# ---------------------------------------------------------------- README

for cmd in "make demo" "make test"; do
    if grep -qF -- "$cmd" README.md; then pass "README has '$cmd'"
    else fail "README has '$cmd'"; fi
done

# ---------------------------------------------------------------- no way out

# The tracked and new files (not the ignored build output); the pattern is
# written so that this file does not match itself.
if git rev-parse --is-inside-work-tree >/dev/null 2>&1; then
    git ls-files -co --exclude-standard -z >"$TMP/files"
else
    find . \( -path ./build -o -path ./.git \) -prune -o -type f -print0 >"$TMP/files"
fi
out=$(xargs -0 grep -I -l -E -e '\.\./shared' -e 'spec/VOD[.]md' <"$TMP/files" 2>/dev/null)
if [ -z "$out" ]; then pass "no file points outside the repository"
else fail "no file points outside the repository" "$(echo $out)"; fi

# ---------------------------------------------------------------- manual pages

# groff is a dependency (scripts/deps.sh): missing, it fails here.
for page in docs/man/vox.1 docs/man/voxd.8; do
    if ! command -v groff >/dev/null; then
        fail "$page renders without warnings" "groff is not installed (make deps)"
        continue
    fi
    warn=$(groff -man -ww -z "$page" 2>&1)
    rc=$?
    if [ "$rc" -eq 0 ] && [ -z "$warn" ]; then pass "$page renders without warnings"
    else fail "$page renders without warnings" "rc $rc: $warn"; fi
done
# The pages' text for the checks below, from the source (rendered text
# hyphenates long options at line ends): escapes and font changes out.
for page in docs/man/vox.1 docs/man/voxd.8; do
    sed -e 's/\\-/-/g' -e 's/\\f[BIRP]//g' -e 's/\\(aq/'"'"'/g' "$page" >"$TMP/$(basename "$page").txt"
done

# ---------------------------------------------------------------- options

# long_opts TEXT-FILE: the --options named in it, one a line
long_opts() { grep -oE -- '--[a-z][a-z0-9-]*' "$1" | sort -u; }
# has FILE OPT: OPT in FILE as a whole option
has() { grep -qE -- "$2([^A-Za-z0-9_-]|$)" "$1"; }

# opts_documented WHO MANTXT DOC HELP...: every long option in the help
# texts appears in the manual page and in the docs page
opts_documented() {
    local who=$1 man=$2 doc=$3 missing_man="" missing_doc="" o
    shift 3
    cat "$@" >"$TMP/help.all"
    for o in $(long_opts "$TMP/help.all"); do
        has "$man" "$o" || missing_man="$missing_man $o"
        has "$doc" "$o" || missing_doc="$missing_doc $o"
    done
    if [ -z "$missing_man" ]; then pass "$who: every --help option is in the manual page"
    else fail "$who: every --help option is in the manual page" "missing:$missing_man"; fi
    if [ -z "$missing_doc" ]; then pass "$who: every --help option is in $doc"
    else fail "$who: every --help option is in $doc" "missing:$missing_doc"; fi
    # the other way: the manual page names no option the program lacks
    local stale=""
    for o in $(long_opts "$man"); do has "$TMP/help.all" "$o" || stale="$stale $o"; done
    if [ -z "$stale" ]; then pass "$who: the manual page names only real options"
    else fail "$who: the manual page names only real options" "not in any --help:$stale"; fi
}

"$VOX" --help >"$TMP/h.vox" 2>&1
for c in voxelize submit render status cancel ping info mesh-info export mesh; do
    "$VOX" "$c" --help >"$TMP/h.$c" 2>&1 || fail "vox $c --help exits 0"
done
"$VOXD" --help >"$TMP/h.voxd" 2>&1 || fail "voxd --help exits 0"
if [ -s "$TMP/h.voxelize" ] && [ -s "$TMP/h.submit" ] && [ -s "$TMP/h.render" ] &&
   [ -s "$TMP/h.voxd" ]; then pass "the --help texts are there"
else fail "the --help texts are there"; fi
opts_documented vox "$TMP/vox.1.txt" docs/cli.md "$TMP/h.vox" "$TMP/h.voxelize" \
    "$TMP/h.submit" "$TMP/h.render" "$TMP/h.status" "$TMP/h.cancel" "$TMP/h.ping" "$TMP/h.info" \
    "$TMP/h.mesh-info" "$TMP/h.export" "$TMP/h.mesh"
opts_documented voxd "$TMP/voxd.8.txt" docs/daemon.md "$TMP/h.voxd"
# vox_mpi has no manual page: its --help's options against docs/mpi.md (it
# prints its help without MPI's launcher: a singleton rank)
# (Open MPI's plugins leave allocations LeakSanitizer cannot name: mpi.sh)
ASAN_OPTIONS="$ASAN_OPTIONS:detect_leaks=0" "$(dirname "$VOX")/vox_mpi" --help >"$TMP/h.vox_mpi" 2>&1 ||
    fail "vox_mpi --help exits 0" "$(tail -3 "$TMP/h.vox_mpi")"
missing=""
for o in $(long_opts "$TMP/h.vox_mpi"); do has docs/mpi.md "$o" || missing="$missing $o"; done
if [ -s "$TMP/h.vox_mpi" ] && [ -z "$missing" ]; then pass "vox_mpi: every --help option is in docs/mpi.md"
else fail "vox_mpi: every --help option is in docs/mpi.md" "missing:$missing"; fi

# ---------------------------------------------------------------- paths, links, layering

python3 - <<'EOF'
import os, re, subprocess

def report(name, bad):
    print(("PASS: " if not bad else "FAIL: ") + name)
    for b in bad[:20]:
        print("  " + b)

docs = ["README.md"] + sorted("docs/" + f for f in os.listdir("docs") if f.endswith(".md"))
top = {p.split("/")[0] for p in subprocess.run(
    ["git", "ls-files"], capture_output=True, text=True).stdout.split() if "/" in p}

def ignored(path):
    return subprocess.run(["git", "check-ignore", "-q", path]).returncode == 0

# `dir/file` in backquotes, for a tracked top-level folder: it must exist
# (globs like expr/expr_*.c must match something; ignored paths such as
# bench/results/ are made by the programs, not shipped).
bad = []
import glob
for d in docs:
    text = open(d).read()
    for m in re.finditer(r"`([A-Za-z0-9_.*-]+/[A-Za-z0-9_./*{}-]*)`", text):
        p = m.group(1)
        if p.split("/")[0] not in top or ignored(p.rstrip("/")):
            continue
        if not glob.glob(p.rstrip("/")):
            bad.append(f"{d}: `{p}` does not exist")
report("every path the docs name exists", bad)

# [text](target#anchor) between the docs: the file exists, the anchor is
# one of its headings (GitHub's slugs)
def slugs(path):
    out = set()
    for line in open(path):
        m = re.match(r"#+\s+(.*)", line)
        if m:
            s = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
            out.add(s)
    return out

bad = []
for d in docs:
    for m in re.finditer(r"\]\(([^)\s]+)\)", open(d).read()):
        t = m.group(1)
        if re.match(r"[a-z]+:", t):
            continue
        f, _, anchor = t.partition("#")
        target = os.path.normpath(os.path.join(os.path.dirname(d), f)) if f else d
        if not os.path.exists(target):
            bad.append(f"{d}: link to {t}: no {target}")
        elif anchor and target.endswith(".md") and anchor not in slugs(target):
            bad.append(f"{d}: link to {t}: no heading '{anchor}' in {target}")
report("every link between the docs resolves", bad)

# docs/layout.md's "may include from" is the Makefile's LAYER_ lines
layers = {}
for line in open("Makefile"):
    m = re.match(r"LAYER_(\w+)\s*:=(.*)", line)
    if m:
        layers[m.group(1)] = set(m.group(2).split())
rows = {}
for line in open("docs/layout.md"):
    m = re.match(r"\|\s*`(\w+)/`\s*\|[^|]*\|([^|]*)\|", line)
    if m:
        rows[m.group(1)] = {x.strip("`/") for x in re.findall(r"`[^`]+`", m.group(2))}
bad = []
if not layers:
    bad.append("no LAYER_ lines in the Makefile")
for mod, inc in layers.items():
    if mod not in rows:
        bad.append(f"module {mod}/ has no row in docs/layout.md")
    elif rows[mod] != inc:
        bad.append(f"{mod}/: docs say {sorted(rows[mod])}, the Makefile {sorted(inc)}")
report("docs/layout.md matches the Makefile's layering", bad)
EOF

# ---------------------------------------------------------------- configuration

"$VOXD" --check-config config/voxd.conf >"$TMP/eff.shipped" 2>&1
check "the shipped voxd.conf loads" test $? -eq 0
# every option voxd has, as printed by --check-config (set or "# key: not set")
sed -nE -e 's/^([a-z_]+) .*/\1/p' -e 's/^# ([a-z_]+): not set.*/\1/p' "$TMP/eff.shipped" |
    sort -u >"$TMP/keys"
[ "$(wc -l <"$TMP/keys")" -ge 20 ] && pass "voxd --check-config names its options" ||
    fail "voxd --check-config names its options" "$(cat "$TMP/keys")"
for f in config/voxd.conf docs/daemon.md "$TMP/voxd.8.txt"; do
    missing=""
    for k in $(cat "$TMP/keys"); do grep -qE "(^|[^a-z_])$k([^a-z_]|$)" "$f" || missing="$missing $k"; done
    if [ -z "$missing" ]; then pass "every configuration option is in $(basename "$f" .txt)"
    else fail "every configuration option is in $(basename "$f" .txt)" "missing:$missing"; fi
done
# Its "#key value" lines are the defaults: uncommented, they change nothing.
sed -E 's/^#([a-z_]+ )/\1/' config/voxd.conf >"$TMP/uncommented.conf"
n=$(grep -cE '^[a-z_]+ ' "$TMP/uncommented.conf")
"$VOXD" --check-config "$TMP/uncommented.conf" >"$TMP/eff.defaults" 2>&1
if [ "$n" -ge 15 ] && cmp -s "$TMP/eff.shipped" "$TMP/eff.defaults"; then
    pass "voxd.conf's $n commented defaults are voxd's defaults"
else
    fail "voxd.conf's commented defaults are voxd's defaults" \
        "$n lines; $(diff "$TMP/eff.shipped" "$TMP/eff.defaults" | head -5)"
fi

# ---------------------------------------------------------------- make install

R=$TMP/root
mk() { env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make --no-print-directory -C "$ROOT" "$@"; }
check "make install DESTDIR PREFIX=/usr" mk install DESTDIR="$R" PREFIX=/usr
installed="usr/bin/vox usr/bin/vox_mpi usr/sbin/voxd usr/share/man/man1/vox.1 usr/share/man/man8/voxd.8
usr/lib/systemd/system/voxd.service etc/voxd/voxd.conf usr/share/doc/voxd/README.md
usr/share/doc/voxd/docs/vod-format.md usr/lib/libvox.a usr/include/vox.h usr/include/vox_limits.h
usr/lib/pkgconfig/libvox.pc usr/lib/voxd/vox-vdb.so"
missing=""
for f in $installed; do [ -f "$R/$f" ] || missing="$missing $f"; done
if [ -z "$missing" ]; then pass "make install installs every file"
else fail "make install installs every file" "missing:$missing"; fi
check "installed programs are executable" test -x "$R/usr/bin/vox" -a -x "$R/usr/sbin/voxd"
# the installed vox finds its OpenVDB module in ../lib/voxd, not the build's
check "installed vox writes a VOD" "$R/usr/bin/vox" voxelize --embedded -w 0 -q \
    -e 'x*x+y*y+z*z-0.5' -r 16 -o "$TMP/installed.vod"
check "installed vox exports .vdb through the installed vox-vdb.so" \
    "$R/usr/bin/vox" export "$TMP/installed.vod" -o "$TMP/installed.vdb"
check "installed voxd.conf is the shipped one" cmp config/voxd.conf "$R/etc/voxd/voxd.conf"
refuse "the unit starts the installed voxd" 0 \
    '^ExecStart=/usr/sbin/voxd --config /etc/voxd/voxd.conf$' cat "$R/usr/lib/systemd/system/voxd.service"
refuse "the unit reloads with the installed voxd" 0 \
    '^ExecReload=/usr/sbin/voxd --check-config /etc/voxd/voxd.conf$' cat "$R/usr/lib/systemd/system/voxd.service"
if grep -v '^#' "$R/usr/lib/systemd/system/voxd.service" | grep -q '/usr/local'; then
    fail "the unit has no path of another prefix" "$(grep -v '^#' "$R/usr/lib/systemd/system/voxd.service" | grep /usr/local)"
else pass "the unit has no path of another prefix"; fi
check "installed voxd accepts the installed voxd.conf" \
    "$R/usr/sbin/voxd" --check-config "$R/etc/voxd/voxd.conf"

# The installed voxd serves with the installed configuration (on a socket
# of this test's), the installed vox talks to it, and it stops on QUIT.
if VOXD="$R/usr/sbin/voxd" start_voxd "$TMP/installed.log" --config "$R/etc/voxd/voxd.conf" --workers 1; then
    pass "installed voxd starts with the installed voxd.conf"
    refuse "installed vox pings the installed voxd" 0 "protocol 1, 1 worker," \
        "$R/usr/bin/vox" --socket "$S" ping
    kill -QUIT "$VOXD_PID"
    if wait_gone "$VOXD_PID" 20 && [ "$WAIT_RC" -eq 0 ]; then pass "installed voxd stops on QUIT, status 0"
    else fail "installed voxd stops on QUIT, status 0" "$(tail -3 "$TMP/installed.log")"; fi
else
    fail "installed voxd starts with the installed voxd.conf" "$(tail -3 "$TMP/installed.log")"
fi

# An edited configuration survives install and uninstall; all else goes.
echo "log_level debug" >>"$R/etc/voxd/voxd.conf"
cp "$R/etc/voxd/voxd.conf" "$TMP/edited.conf"
check "make install again" mk install DESTDIR="$R" PREFIX=/usr
check "make install keeps an existing voxd.conf" cmp "$TMP/edited.conf" "$R/etc/voxd/voxd.conf"
check "make uninstall" mk uninstall DESTDIR="$R" PREFIX=/usr
left=$(cd "$R" && find . -type f | sort)
if [ "$left" = "./etc/voxd/voxd.conf" ]; then pass "make uninstall removes all but the edited voxd.conf"
else fail "make uninstall removes all but the edited voxd.conf" "left: $(echo $left)"; fi
rm -f "$R/etc/voxd/voxd.conf"
check "make install into an empty root" mk install DESTDIR="$R" PREFIX=/usr

# libvox as a client program takes it: pkg-config finds it, the program
# builds against the installed header and archive alone, and it talks to a
# socket (a refused connection is a typed error, not a crash).
cat >"$TMP/client.c" <<'C'
#include <stdio.h>
#include <vox.h>
int main(int argc, char **argv)
{
    vox_client *c;
    vox_error e;
    int rc = vox_connect(argc > 1 ? argv[1] : "/nonexistent", NULL, &c, &e);
    printf("%d %s\n", rc, e.message);
    return rc == 0 ? 0 : 1;
}
C
pc() { PKG_CONFIG_SYSROOT_DIR="$R" PKG_CONFIG_LIBDIR="$R/usr/lib/pkgconfig" pkg-config "$@"; }
refuse "pkg-config finds the installed libvox" 0 "-I$R/usr/include" pc --cflags libvox
# the archive by name (-l:libvox.a): -lvox finds the shared library first
# (install.sh links against that one)
if cc -o "$TMP/client" "$TMP/client.c" $(pc --cflags libvox) \
       $(pc --libs --static libvox | sed 's/-lvox\b/-l:libvox.a/') \
       >"$TMP/cc.log" 2>&1; then pass "a client builds with the installed libvox alone"
else fail "a client builds with the installed libvox alone" "$(head -5 "$TMP/cc.log")"; fi
refuse "that client gets a typed error from a missing socket" 1 "^-2 .*no voxd answering" \
    "$TMP/client" "$TMP/no.sock"
# (nm must read it: its client functions are there, the engine's are not)
if ! nm "$R/usr/lib/libvox.a" >"$TMP/nm.out" 2>&1 || ! grep -q ' T vox_connect$' "$TMP/nm.out"; then
    fail "libvox holds only the client's code" "nm: $(head -3 "$TMP/nm.out")"
elif grep -Eq ' T (engine_|daemon_|subdiv_|expr_)' "$TMP/nm.out"; then
    fail "libvox holds only the client's code" "$(grep -E ' T (engine_|daemon_|subdiv_|expr_)' "$TMP/nm.out" | head -3)"
else pass "libvox holds only the client's code"; fi
check "make uninstall of an unedited install" mk uninstall DESTDIR="$R" PREFIX=/usr
left=$(cd "$R" && find . -type f | wc -l)
check "make uninstall leaves no file of an unedited install" test "$left" -eq 0

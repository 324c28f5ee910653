#!/usr/bin/env python3
"""The layering of the tree, checked over the sources and the objects.

The Makefile's LAYER_<module> lines say which folders each module may
include from.  This checks, printing PASS:/FAIL: lines:
  - the LAYER graph itself has no cycle;
  - every #include "x.h" of a module's files resolves to its own folder or
    to a folder its LAYER line allows;
  - the link-level graph (a symbol one object uses and another defines,
    read with nm from a build) runs only along the LAYER graph between
    modules, and has no cycle between the files of one module.  This is
    the real dependency: a header shared by two files that call each other
    hides a cycle from the include graph, not from the symbols;
  - every global symbol (nm's T, D, B, R) a module's objects define starts
    with one of the module's prefixes (PREFIXES below), so a name says
    its folder.
usage: layering.py ROOT BUILD_DIR
"""
import os, re, subprocess, sys

# The prefixes of each module's global symbols.  A module that is a set of
# small modules (common/, client/) is PARTS: a file's symbols start with
# the first word of its name (common/job_meta.c: job_, client/render_mesh.c:
# render_).  libvox's public calls are vox_*, its insides libvox_*.  `main`
# is any program's; protobuf-c's generated code is not checked.
PARTS = "parts"
PREFIXES = {
    "mpi": ("mpi_",),
    "client": PARTS,
    "daemon": ("daemon_",),
    "config": ("config_",),
    "libvox": ("vox_", "libvox_"),
    "engine": ("engine_",),
    "worker": ("worker_",),
    "subdiv": ("subdiv_",),
    "shm": ("shm_",),
    "csg": ("csg_",),
    "iso": ("iso_",),
    "mesh": ("mesh_",),
    "proto": ("proto_",),
    "vod": ("vod_",),
    "octree": ("octree_",),
    "expr": ("expr_",),
    "ival": ("ival_",),
    "common": PARTS,
}

root, build = sys.argv[1], sys.argv[2]
ok = True

def report(passed, name, detail=""):
    global ok
    print(("PASS: " if passed else "FAIL: ") + name)
    if not passed:
        ok = False
        if detail:
            print("  " + detail)

def find_cycle(graph):
    """A cycle as a list of nodes, or None (iterative DFS, three colours)."""
    colour = {n: 0 for n in graph}
    for start in sorted(graph):
        if colour[start]:
            continue
        stack = [(start, iter(sorted(graph[start])))]
        path = [start]
        colour[start] = 1
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                colour[node] = 2
                stack.pop()
                path.pop()
            elif colour.get(nxt, 2) == 1:
                return path[path.index(nxt):] + [nxt]
            elif colour.get(nxt, 2) == 0:
                colour[nxt] = 1
                stack.append((nxt, iter(sorted(graph[nxt]))))
                path.append(nxt)
    return None

makefile = open(os.path.join(root, "Makefile")).read()
modules = re.search(r"^MODULES\s*:=(.*)$", makefile, re.M).group(1).split()
layer = {m: set() for m in modules}
for m, deps in re.findall(r"^LAYER_(\w+)\s*:=(.*)$", makefile, re.M):
    layer[m] = set(deps.split())
report(len(modules) >= 8 and all(m in layer for m in modules),
       "layering: every module has a LAYER line (%d modules)" % len(modules))
cyc = find_cycle(layer)
report(cyc is None, "layering: the modules' LAYER graph has no cycle",
       " -> ".join(cyc or []))

# Source level: includes.
home = {}  # header name -> module
for m in modules:
    for f in os.listdir(os.path.join(root, m)):
        if f.endswith(".h"):
            home[f] = m
home["voxd.pb-c.h"] = "proto"  # generated from proto/voxd.proto
bad = []
for m in modules:
    for f in sorted(os.listdir(os.path.join(root, m))):
        if not f.endswith((".c", ".h")):
            continue
        for inc in re.findall(r'^#include "([^"]+)"', open(os.path.join(root, m, f)).read(), re.M):
            h = home.get(inc)
            if h is None:
                bad.append("%s/%s includes %s, which no module holds" % (m, f, inc))
            elif h != m and h not in layer[m]:
                bad.append("%s/%s includes %s/%s" % (m, f, h, inc))
report(not bad, "layering: every include follows the LAYER lines", "; ".join(bad))

# Link level: symbols.
globals_of = {}  # object -> its T, D, B and R symbols
def symbols(obj):
    out = subprocess.run(["nm", "-P", obj], capture_output=True, text=True, check=True).stdout
    defined, used, glob = set(), set(), set()
    for line in out.splitlines():
        parts = line.split()
        if len(parts) < 2:
            continue
        (used if parts[1] == "U" else defined if parts[1] in "TDBRCGSV" else set()).add(parts[0])
        if parts[1] in "TDBR":
            glob.add(parts[0])
    globals_of[obj] = glob
    return defined, used

objs = {}
for m in modules:
    d = os.path.join(build, m)
    if not os.path.isdir(d):
        continue
    for f in os.listdir(d):
        # only objects of sources that exist (a build dir keeps stale ones)
        if f.endswith(".o") and os.path.exists(os.path.join(root, m, f[:-2] + ".c")):
            objs["%s/%s" % (m, f[:-2])] = symbols(os.path.join(d, f))
gen = os.path.join(build, "proto", "voxd.pb-c.o")
if os.path.exists(gen):
    objs["proto/voxd.pb-c"] = symbols(gen)
report(len(objs) >= 30, "layering: objects read from %s (%d)" % (build, len(objs)))
owner = {}
for name, (defined, _) in objs.items():
    for s in defined:
        owner.setdefault(s, name)
files = {n: set() for n in objs}
bad = set()
for name, (_, used) in objs.items():
    for s in used:
        o = owner.get(s)
        if o is None or o == name:
            continue
        files[name].add(o)
        a, b = name.split("/")[0], o.split("/")[0]
        if a != b and b not in layer[a]:
            bad.add("%s uses %s of %s" % (name, s, o))
report(not bad, "layering: calls between modules follow the LAYER lines",
       "; ".join(sorted(bad)))
for m in modules:
    sub = {n: {d for d in deps if d.startswith(m + "/")}
           for n, deps in files.items() if n.startswith(m + "/")}
    cyc = find_cycle(sub)
    report(cyc is None, "layering: no cycle between the files of %s/" % m,
           " -> ".join(cyc or []))

# Names: every global symbol starts with its module's prefix.
bad = []
for name in sorted(objs):
    m, f = name.split("/")
    if name == "proto/voxd.pb-c":
        continue
    allowed = PREFIXES.get(m)
    if allowed is None:
        bad.append("module %s/ has no line in layering.py's PREFIXES" % m)
        continue
    if allowed == PARTS:
        allowed = (f.split("_")[0] + "_",)
    for s in sorted(globals_of[os.path.join(build, m, f + ".o")]):
        if s != "main" and not s.startswith(allowed):
            bad.append("%s in %s/%s.c (allowed: %s)" % (s, m, f, " ".join(p + "*" for p in allowed)))
report(not bad, "layering: every global symbol starts with its module's prefix (%d modules)"
       % len(modules), "; ".join(bad[:40]) + (" ... %d in all" % len(bad) if len(bad) > 40 else ""))
sys.exit(0 if ok else 1)

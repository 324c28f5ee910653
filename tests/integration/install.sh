#!/bin/bash
# make install as a Debian user expects it: into a temporary root (DESTDIR)
# under PREFIX=/usr/local, then
#  - libvox: the shared library with its soname and links beside the
#    archive; a client built with `pkg-config --libs libvox` (no --static)
#    links against libvox.so.1 and runs; the library exports vox.h's calls
#    alone;
#  - the Python reader voxd in the system python3's path (Debian's
#    dist-packages), imported from there; and `pip install
#    --no-build-isolation` into a venv without the network (--no-index);
#  - vox's bash completion: sourced, it completes commands, options (read
#    from the installed vox's --help) and option values;
#  - make uninstall removes every file again.
. "$(dirname "$0")/lib.sh"

R=$TMP/root
P=/usr/local
mk() { env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make --no-print-directory -C "$ROOT" "$@"; }
if ! mk install DESTDIR="$R" PREFIX=$P >"$TMP/install.log" 2>&1; then
    fail "make install DESTDIR PREFIX=$P" "$(tail -5 "$TMP/install.log")"
    exit 0
fi
pass "make install DESTDIR PREFIX=$P"
L=$R$P/lib

# ---------------------------------------------------------------- libvox.so
so=$(cd "$L" && ls libvox.so.1.*.* 2>/dev/null)
if [ -n "$so" ] && [ -f "$L/$so" ] && [ "$(readlink "$L/libvox.so.1")" = "$so" ] &&
   [ "$(readlink "$L/libvox.so")" = libvox.so.1 ] && [ -f "$L/libvox.a" ]; then
    pass "libvox.so.1.x.y, its links libvox.so.1 and libvox.so, beside libvox.a"
else
    fail "libvox.so.1.x.y, its links libvox.so.1 and libvox.so, beside libvox.a" "$(ls -l "$L")"
fi
refuse "libvox.so's soname is libvox.so.1" 0 "SONAME.*\[libvox\.so\.1\]" readelf -d "$L/libvox.so"
others=$(nm -D --defined-only "$L/libvox.so" | awk '$2 ~ /[TDBR]/ && $3 !~ /^vox_/ {print $3}')
n=$(nm -D --defined-only "$L/libvox.so" | awk '$3 ~ /^vox_/' | wc -l)
if [ -z "$others" ] && [ "$n" -ge 10 ]; then pass "libvox.so exports vox.h's $n calls alone"
else fail "libvox.so exports vox.h's calls alone" "$n vox_ calls; others: $(echo $others | head -c 200)"; fi

cat >"$TMP/client.c" <<'C'
#include <stdio.h>
#include <vox.h>
int main(int argc, char **argv)
{
    vox_client *c;
    vox_error e;
    int rc = vox_connect(argc > 1 ? argv[1] : "/nonexistent", NULL, &c, &e);
    printf("%d %s (%s)\n", rc, e.message, vox_strerror(rc));
    return rc == 0 ? 0 : 1;
}
C
pc() { PKG_CONFIG_SYSROOT_DIR="$R" PKG_CONFIG_LIBDIR="$L/pkgconfig" pkg-config "$@"; }
libs=$(pc --libs libvox)
if cc -o "$TMP/client" "$TMP/client.c" $(pc --cflags libvox) $libs >"$TMP/cc.log" 2>&1; then
    pass "a client links with pkg-config --libs libvox ($libs)"
else fail "a client links with pkg-config --libs libvox" "$(head -5 "$TMP/cc.log")"; fi
refuse "the client needs libvox.so.1" 0 "NEEDED.*\[libvox\.so\.1\]" readelf -d "$TMP/client"
refuse "the client runs on the installed libvox.so.1 (a typed error from a missing socket)" 1 \
    "^-2 .*no voxd answering" env LD_LIBRARY_PATH="$L" "$TMP/client" "$TMP/no.sock"
refuse "it is the installed library that it loads" 0 "libvox\.so\.1 => $L/libvox\.so\.1" \
    env LD_LIBRARY_PATH="$L" ldd "$TMP/client"

# ---------------------------------------------------------------- python
PY=/usr/bin/python3
[ -x "$PY" ] || PY=python3
ver=$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
site=$R$P/lib/python$ver/dist-packages
if "$PY" -c "import sys; sys.exit(0 if '$P/lib/python$ver/dist-packages' in sys.path else 1)"; then
    pass "$P/lib/python$ver/dist-packages is in $PY's path"
else fail "$P/lib/python$ver/dist-packages is in $PY's path" "$("$PY" -c 'import sys; print(sys.path)')"; fi
"$VOX" voxelize --embedded -w 0 -q -e 'x*x+y*y+z*z-0.5' -r 20 -o "$TMP/s.vod"
want=$("$VOX" info "$TMP/s.vod" | sed -n 's/.*voxels *\([0-9]*\) non-empty.*/\1/p')
got=$(cd "$TMP" && PYTHONPATH="$site" "$PY" -c "
import sys, voxd
assert voxd.__file__.startswith('$site'), voxd.__file__
print(int((voxd.read('s.vod').occupancy != 0).sum()))" 2>&1)
if [ -n "$want" ] && [ "$got" = "$want" ]; then pass "the installed voxd reads a VOD ($want voxels, as vox info)"
else fail "the installed voxd reads a VOD" "vox info $want; voxd: $got"; fi

# pip without the network: a venv that sees Debian's numpy and setuptools,
# the package built by them (--no-build-isolation), nothing fetched (--no-index)
cp -r "$ROOT/python" "$TMP/pysrc"   # pip builds in the source tree
rm -rf "$TMP/pysrc/build" "$TMP/pysrc"/*.egg-info
if "$PY" -m venv --system-site-packages "$TMP/venv" >"$TMP/venv.log" 2>&1 &&
   "$TMP/venv/bin/pip" install --no-index --no-build-isolation --no-deps "$TMP/pysrc" \
       >>"$TMP/venv.log" 2>&1 &&
   got=$(cd "$TMP" && "$TMP/venv/bin/python" -c "
import voxd
assert '/venv/' in voxd.__file__, voxd.__file__
print(int((voxd.read('s.vod').occupancy != 0).sum()))") && [ "$got" = "$want" ]; then
    pass "pip install --no-index --no-build-isolation ./python into a venv, offline"
else fail "pip install --no-index --no-build-isolation ./python into a venv, offline" \
    "$(tail -3 "$TMP/venv.log")"; fi

# ---------------------------------------------------------------- completion
comp=$R$P/share/bash-completion/completions/vox
# complete LINE: the completions of LINE's last word with the installed vox
complete_line() {
    PATH="$R$P/bin:$PATH" bash -c '
        . "$1"; read -ra COMP_WORDS <<<"$2"
        [[ $2 == *" " ]] && COMP_WORDS+=("")
        COMP_CWORD=$((${#COMP_WORDS[@]} - 1)); _vox; echo "${COMPREPLY[*]}"' _ "$comp" "$1"
}
compl() { # NAME LINE WORD...: every WORD is among LINE's completions
    local n=$1 line=$2 got w miss=""
    shift 2
    got=" $(complete_line "$line") "
    for w in "$@"; do [[ $got == *" $w "* ]] || miss="$miss $w"; done
    if [ -z "$miss" ]; then pass "completion: $n"; else fail "completion: $n" "'$line' gave:$got"; fi
}
if [ -f "$comp" ] && bash -n "$comp"; then pass "bash completion installed in share/bash-completion/completions"
else fail "bash completion installed in share/bash-completion/completions"; fi
compl "commands" "vox ex" export
compl "commands after --socket" "vox --socket /tmp/s vo" voxelize
compl "export's options" "vox export a.vod --fo" --format
compl "voxelize's options" "vox voxelize --ch" --channel
compl "export formats" "vox export a.vod --format " nrrd raw binvox vti vdb
compl "channels" "vox voxelize --channel s" surface
mkdir -p "$TMP/c" && touch "$TMP/c/a.vod" "$TMP/c/b.txt"
compl "VOD files for info" "vox info $TMP/c/" "$TMP/c/a.vod"
got=$(complete_line "vox info $TMP/c/")
if [[ $got != *b.txt* ]]; then pass "completion: info offers no other files"
else fail "completion: info offers no other files" "$got"; fi

# ---------------------------------------------------------------- uninstall
check "make uninstall" mk uninstall DESTDIR="$R" PREFIX=$P
left=$(cd "$R" && find . ! -type d ! -path ./etc/voxd/voxd.conf | sort)
if [ -z "$left" ]; then pass "make uninstall removes libvox.so, its links, voxd.py and the completion"
else fail "make uninstall removes libvox.so, its links, voxd.py and the completion" "left: $(echo $left)"; fi

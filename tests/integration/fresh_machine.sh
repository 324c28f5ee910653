#!/bin/bash
# The README's first step on a fresh Debian 12 machine: `make demo` must install
# the build's packages, then build and run, in one go. A machine without the
# packages is played by stubs first in PATH: until the stub apt-get has been
# asked to install, dpkg-query and pkg-config find nothing; after that they
# answer as the real ones (the packages are really here, or the build could
# not run). Each stub call is logged with the time it came, before or after
# the install, so the test sees that no flags were asked of pkg-config before
# there was a pkg-config to ask: the Makefile once did that when make read it,
# and the first `make demo` failed to link.
. "$(dirname "$0")/lib.sh"

# A copy of the source tree (tracked files and new ones not ignored, as they
# are on disk, so uncommitted work is tested too), without any build output.
src="$TMP/src"
mkdir -p "$src"
if git -C "$ROOT" rev-parse --is-inside-work-tree >/dev/null 2>&1; then
    git -C "$ROOT" ls-files -z --cached --others --exclude-standard |
        while IFS= read -r -d '' f; do [ -e "$f" ] && printf '%s\0' "$f"; done |
        tar -C "$ROOT" --null -T - -cf - | tar -C "$src" -xf -
else
    tar -C "$ROOT" --exclude=./build -cf - . | tar -C "$src" -xf -
fi

stubs="$TMP/bin" state="$TMP/state"
mkdir -p "$stubs" "$state"
real_pkgconfig=$(command -v pkg-config) real_dpkgquery=$(command -v dpkg-query)
# Evaluated by each stub at its call, not here.
phase='$([ -e '"$state"'/installed ] && echo after || echo before)'
cat >"$stubs/apt-get" <<EOF
#!/bin/sh
echo "$phase apt-get \$*" >>"$state/log"
if [ "\$1" = install ]; then
    shift
    for a; do case \$a in -*) ;; *) echo "\$a" >>"$state/asked" ;; esac; done
    touch "$state/installed"
fi
EOF
cat >"$stubs/dpkg-query" <<EOF
#!/bin/sh
echo "$phase dpkg-query \$*" >>"$state/log"
[ -e "$state/installed" ] && exec "$real_dpkgquery" "\$@"
for a; do last=\$a; done
echo "dpkg-query: no packages found matching \$last" >&2
exit 1
EOF
# pkg-config also plays a machine where one module is missing after the
# install: the one named in \$HIDE_MODULE.
cat >"$stubs/pkg-config" <<EOF
#!/bin/sh
echo "$phase pkg-config \$*" >>"$state/log"
[ -e "$state/installed" ] || exit 1
for a; do [ "\$a" = "\${HIDE_MODULE:-}" ] && exit 1; done
exec "$real_pkgconfig" "\$@"
EOF
# deps.sh runs apt-get through sudo when not root; the real sudo would reset
# PATH to the real apt-get.
printf '#!/bin/sh\nexec "$@"\n' >"$stubs/sudo"
chmod +x "$stubs"/*

# make as a user runs it: no flags of the make running this test.
fresh_make() {
    (cd "$src" && env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL -u V -u BUILD \
        PATH="$stubs:$PATH" make "$@")
}

# Plain `make` installs nothing: on the bare machine it names what is missing.
refuse "make without the packages names the missing one and installs nothing" 2 \
    'module zlib not found \(Debian package zlib1g-dev; make deps installs' fresh_make -j2
check "make without the packages did not call apt-get" \
    bash -c "test -s '$state/log' && ! grep -q apt-get '$state/log'"  # (the stubs' log there)
: >"$state/log"

fresh_make -j2 demo >"$TMP/demo.log" 2>&1
rc=$?
if [ "$rc" -eq 0 ]; then pass "first make demo on a fresh machine succeeds"
else fail "first make demo on a fresh machine succeeds" "exit $rc: $(tail -5 "$TMP/demo.log")"; fi
for p in pkg-config zlib1g-dev libpng-dev libxxhash-dev libuv1-dev libprotobuf-c-dev \
    protobuf-c-compiler; do
    check "apt-get was asked to install $p" grep -qx "$p" "$state/asked"
done
check "apt-get install ran once" test "$(grep -c 'apt-get install' "$state/log")" -eq 1
check "pkg-config was not asked before the install" \
    bash -c "test -s '$state/log' && ! grep -q '^before pkg-config' '$state/log'"
check "pkg-config was asked after the install" grep -q '^after pkg-config --cflags' "$state/log"
check "the demo wrote a VOD that vox info reads" "$src/build/release/vox" info "$src/scene1.vod"
check "the demo wrote a PNG" bash -c "head -c 8 '$src/scene1.png' | od -An -tx1 | \
    grep -q '89 50 4e 47 0d 0a 1a 0a'"

# Installed but a module still missing: the build stops naming its package.
export HIDE_MODULE=libuv
refuse "a module missing after deps is named with its package" 2 \
    'pkg-config module libuv not found \(Debian package libuv1-dev' \
    fresh_make -j2 BUILD=build/hidden

# Only the goals in DEPS_GOALS install before configuring: a new goal with deps
# as a prerequisite missing there would configure before its deps ran.
needs=$(sed -nE 's/^([a-z][a-z-]*):(.*[[:space:]])?deps([[:space:]].*)?$/\1/p' "$src/Makefile" | sort)
listed=$(sed -nE 's/^DEPS_GOALS[[:space:]]*:=//p' "$src/Makefile" | tr -s ' \t' '\n' | grep . | sort)
unlisted=$(comm -23 <(echo "$needs") <(echo "$listed"))
if [ -n "$needs" ] && [ -z "$unlisted" ]; then pass "DEPS_GOALS lists every goal with deps as a prerequisite"
else fail "DEPS_GOALS lists every goal with deps as a prerequisite" "goals: '$needs', unlisted: '$unlisted'"; fi

#!/bin/sh
# Install the Debian packages voxd needs to build, test and fuzz, when missing
# (valgrind: tests/integration/valgrind.sh; python3 and procps: the daemon's
# integration tests, for the hand-written protocol client and pgrep/ps;
# python3-numpy: python/voxd and the export tests; libopenmpi-dev and
# openmpi-bin: vox_mpi, built with mpicc's flags, and its tests under mpirun;
# libopenvdb-dev and libboost-dev, whose headers libopenvdb's include but
# which Debian 12's libopenvdb-dev does not pull in: vox export's .vdb module;
# libopenvdb-tools: vdb_print, which reads the .vdb exports back in the tests;
# python3-vtk9: VTK's readers, which open the NRRD and .vti exports in the tests;
# python3-pip, python3-setuptools and python3-venv: the offline pip install of
# python/ that the tests run; libjson-c-dev: the glTF loader's JSON).
set -e
PKGS="build-essential pkg-config zlib1g-dev libdeflate-dev libpng-dev libxxhash-dev libuv1-dev \
libprotobuf-c-dev protobuf-c-compiler libcriterion-dev clang libclang-rt-14-dev \
valgrind python3 python3-numpy procps groff-base libopenmpi-dev openmpi-bin \
libopenvdb-dev libboost-dev libopenvdb-tools python3-vtk9 \
python3-pip python3-setuptools python3-venv libjson-c-dev"
missing=""
for p in $PKGS; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
[ -z "$missing" ] && exit 0
echo "deps: installing$missing"
if ! command -v apt-get >/dev/null 2>&1; then
    echo "deps: no apt-get here: install the equivalents of$missing by hand" >&2
    exit 1
fi
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO=sudo
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing

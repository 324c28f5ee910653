#!/bin/bash
# The layering of the tree (tests/integration/layering.py says what it
# checks), over the sources and the release build's objects.
. "$(dirname "$0")/lib.sh"
python3 tests/integration/layering.py "$ROOT" "$ROOT/build/release"

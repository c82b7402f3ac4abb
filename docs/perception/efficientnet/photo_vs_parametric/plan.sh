#!/bin/bash
# Run 2026-11-28 (results beside this file). One H100, ~22 min held. Does the photo library (which holds RS_290's labelled
# wheel-path strips as pothole assets) find the real strips that parametric defects miss? Zero-shot on the full
# photo set vs the parametric set, seeds 0 and 1, 4,500 steps, evaluated on val and on the train frames (--select).
# Rule fixed before: the photo set is preferred for zero-shot if train pothole rises with its interval above 0 and
# train mIoU does not fall. Staging (7 packs of 20 MiB since 2026-11-28): packs 1-7 -> /root/roadtwin-stage;
# .dev_pc/z1 and .dev_pc/z2 (real.tar, photo_surfaces) -> /root/stage_z;
# .dev_pc/c2..c4 (photos.part00..02) -> /root/stage_ph. Each fits one call beside the 34 MiB tree; if the tree
# grows, re-pack (bench/gpu_pack.py --skip-download .gpu/wheels --extra-wheels .gpu/extra --reserve-mib 8).
LOG=/root/logs_j; mkdir -p $LOG
exec > $LOG/plan.out 2>&1
set -x
cd /root/rt
stamp(){ echo "$(date +%T) $*" >> $LOG/times.txt; }
stamp start
mkdir -p /root/real /root/wheels /root/photos && tar xf /root/stage_z/real.tar -C /root/real
cat /root/stage_ph/photos.part0* | tar xf - -C /root/photos
rm -rf /root/photo_surfaces && cp -r /root/stage_z/photo_surfaces /root/photo_surfaces
. /root/roadtwin-stage/unpack.sh
export PYTHONPATH=/root/rt:/root/rt/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
nvidia-smi > $LOG/nvidia.txt 2>&1
S="highway_a highway_b highway_c highway_d highway_e"
G=docs/perception/efficientnet/gpu_synthetic.sh
SSET=/root/np bash $G compose --scenes $S --weights pothole=2,crack=12 --no-photo > $LOG/compose_np.txt 2>&1; stamp "composed np rc=$?"
SSET=/root/ph bash $G compose --scenes $S --weights pothole=2,crack=12 > $LOG/compose_ph.txt 2>&1; stamp "composed ph rc=$?"
for s in np ph; do SSET=/root/$s FRAMES=1000 bash $G render $S > $LOG/render_$s.txt 2>&1; stamp "rendered $s rc=$?"; done
P="python3 bench/perception.py"
for s in np ph; do
  $P suite --real /root/real --synthetic /root/$s/synthetic --select /root/real/train --seeds 0 1 --arms e --parallel 2 \
    --out /root/z_$s > $LOG/z_$s.txt 2>&1 &
done
wait; stamp "trained"
for s in np ph; do mkdir -p $LOG/z_$s; cp /root/z_$s/*.json $LOG/z_$s/; cp -r /root/z_$s/logs $LOG/z_$s/run_logs; done
touch $LOG/DONE

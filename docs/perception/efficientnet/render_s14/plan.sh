#!/bin/bash
# Session 14 plan a (one H100): render rate end to end, new (the finishing processes plan the frames while the
# scene uploads) vs old (dbc49a1), alternating, 3 runs each, 3,000 frames; then a CUDA render with --events
# (the event drive now starts after the finishing processes fork).
LOG=/root/logs; mkdir -p $LOG
exec > $LOG/plan.out 2>&1
set -x
cd /root/rt
stamp(){ echo "$(date +%T) $*" >> $LOG/times.txt; }
. /root/roadtwin-stage/unpack.sh
B=$PYTHONPATH
export PYTHONPATH=/root/rt:/root/rt/plugins:$B PYTHONUNBUFFERED=1
mkdir -p /root/old && tar xzf /root/rt/.dev_rt/old.tgz -C /root/old
nvidia-smi > $LOG/nvidia.txt 2>&1; nproc >> $LOG/nvidia.txt
stamp start
python3 -m roadtwin_core.cli compose stages/town.usda -o /root/town > $LOG/compose_town.log 2>&1; stamp "compose town rc=$?"
rt() {  # name, code root
  PYTHONPATH=$2:$2/plugins:$B python3 bench/render_throughput.py --stage /root/town/town.usda --device cuda --frames 3000 --warmup 8 > $LOG/rt_$1.txt 2>&1
  stamp "rt $1 rc=$?"
}
rt new_1 /root/rt; rt old_1 /root/old; rt new_2 /root/rt; rt old_2 /root/old; rt new_3 /root/rt; rt old_3 /root/old
python3 -m roadtwin_core.cli render /root/town/town.usda --frames 1200 --device cuda --rig survey --views defects:0.5:clear --randomize --classmap builtin:road_defects_br --events --event-frames 20 -o /root/ev > $LOG/render_events.txt 2>&1
stamp "render events rc=$?"
python3 -c "import json; m=json.load(open('/root/ev/meta.json')); r=m['render']; print(r['frames'], r['events'], r['device'], r['timings_s'], r['phase_timings_s'])" >> $LOG/render_events.txt 2>&1
touch $LOG/DONE

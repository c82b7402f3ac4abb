set -e
cd /work/main
R=.venv/bin/roadtwin
mkdir -p /tmp/zs/photos
ls ../shared/data/road_defects_br/train_full/images/*.jpg | awk 'NR%5==0' > /tmp/zs/list.txt
rm -rf /tmp/zs/photos/*; while read f; do ln -sf "$(realpath $f)" /tmp/zs/photos/; done < /tmp/zs/list.txt
cp ../shared/data/road_defects_br/LICENSE /tmp/zs/photos/ 2>/dev/null || true
time $R reconstruct photos /tmp/zs/photos --labels ../shared/data/road_defects_br/train_full/labels -o /tmp/zs/lib
time $R compose /tmp/zs/highway_real.usda --defects 400 --library /tmp/zs/lib -o /tmp/zs/hw
time $R render /tmp/zs/hw/town.usda --rig survey --views defects:0.5:clear --randomize --classmap builtin:road_defects_br --frames 600 --size 512x320 --executor local -o /tmp/zs/render

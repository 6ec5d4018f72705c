#!/bin/bash
# ctest world2_smoke: the generator's self-test, then one small cell on disk (in mm and in um) checked
# for its files and truth.json's fields.
set -eu
gen=$1; dir=$2
rm -rf "$dir"; mkdir -p "$dir"
"$gen" --selftest
"$gen" --out "$dir/mm" --seed 5 --small
"$gen" --out "$dir/um" --seed 5 --small --unit um
python3 - "$dir" <<'PY'
import json, os, sys
d = sys.argv[1]
a = json.load(open(os.path.join(d, "mm", "truth.json")))
b = json.load(open(os.path.join(d, "um", "truth.json")))
assert os.path.exists(os.path.join(d, "mm", "job.yaml"))
for s in a["scans"]:
    assert os.path.getsize(os.path.join(d, "mm", s["file"])) > 200, s["file"]
    assert "trap" in s and "fiducial_points" in s and len(s["T_machine_scan"]) == 4
for f in a["fiducials"]:
    assert os.path.exists(os.path.join(d, "mm", "models", "fiducial_%s.stl" % f["name"]))
# the same cell in um: every length times 1000, same scans
assert len(a["scans"]) == len(b["scans"])
for s, t in zip(a["scans"], b["scans"]):
    for i in range(3):
        assert abs(s["T_machine_scan"][i][3] * 1000 - t["T_machine_scan"][i][3]) < 1e-6 * max(1, abs(t["T_machine_scan"][i][3]))
    assert s["trap"] == t["trap"] and s["points"] == t["points"]
print("world2 files ok:", len(a["scans"]), "scans,", sum(1 for s in a["scans"] if s["trap"]), "traps")
PY

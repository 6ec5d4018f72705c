#!/bin/sh
# Writes into OUT: scan_roi.ply (data.ply cropped to the README's region of interest, centre (0,120,400) mm,
# size 260x360x200 mm, x y z only) and the partloc jobs that treat the housing CAD as a fiducial at identity:
#   job_full.yaml / job_roi.yaml            no scanner block (whole scan / cropped scan)
#   job_roi_noise<N>.yaml                   scanner: {point_spacing: S, noise: N} for each N in NOISES
# Usage: make_jobs.sh OUT [DATA_DIR] ; env NOISES="1 2" SPACING=2.6 (mm)
set -eu
OUT=$1
DATA=${2:-/work/shared/data/real/sick_housing}
NOISES=${NOISES:-"0.5 1 2 3"}
SPACING=${SPACING:-2.6}
mkdir -p "$OUT"
awk 'BEGIN{cx=0; cy=120; cz=400; hx=130; hy=180; hz=100}
     /^end_header/{body=1; next}
     body && NF>=3 && $1>=cx-hx && $1<=cx+hx && $2>=cy-hy && $2<=cy+hy && $3>=cz-hz && $3<=cz+hz {
       p[n++]=$1" "$2" "$3 }
     END{print "ply\nformat ascii 1.0\nelement vertex " n "\nproperty float x\nproperty float y\nproperty float z\nend_header";
         for(i=0;i<n;i++) print p[i]}' "$DATA/data.ply" > "$OUT/scan_roi.ply.tmp"
mv "$OUT/scan_roi.ply.tmp" "$OUT/scan_roi.ply"
rel_data=$(realpath --relative-to="$OUT" "$DATA")
job() {  # job FILE SCAN [SCANNER_LINES]
  {
    echo "units: mm"
    [ -n "${3:-}" ] && printf '%s\n' "$3"
    echo "fiducials:"
    echo "  - name: housing"
    echo "    model: $rel_data/V2D63xModel.ply"
    echo "    pose: {origin: [0, 0, 0], euler_xyz_deg: [0, 0, 0]}"
    echo "    moves_with: []"
    echo "workpiece:   # needed by the contract only: the same CAD as reference surfaces, datum at identity"
    echo "  reference_surfaces: $rel_data/V2D63xModel.ply"
    echo "  datum: {origin: [0, 0, 0], euler_xyz_deg: [0, 0, 0]}"
    echo "  moves_with: []"
    echo "scans:"
    echo "  - {file: $2}"
  } > "$OUT/$1"
}
job job_full.yaml "$rel_data/data.ply"
job job_roi.yaml scan_roi.ply
for n in $NOISES; do
  job "job_roi_noise$n.yaml" scan_roi.ply "scanner: {point_spacing: $SPACING, noise: $n}"
  job "job_full_noise$n.yaml" "$rel_data/data.ply" "scanner: {point_spacing: $SPACING, noise: $n}"
done
echo "$OUT: $(sed -n 3p "$OUT/scan_roi.ply" | cut -d' ' -f3) points in the region of interest"

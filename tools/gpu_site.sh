#!/usr/bin/env bash
# Pack the `warp` extra's packages for a GPU machine that has no network and takes files in
# pieces (tools/gpu_check.sh's machine: Python 3.12, torch but no mujoco or warp):
#   bash tools/gpu_site.sh [PART_MB]
# Downloads mujoco, mujoco-core, mujoco-warp and warp-lang wheels for CPython 3.12 on x86-64
# Linux, unpacks them into one site folder without warp's CPU compiler (warp-clang.so, 69 MB: the
# GPU build compiles through NVRTC inside warp.so) and its examples, packs it with xz (about
# 92 MB, 2-3 minutes on 2 cores) and splits it into parts of PART_MB (default: what fits beside
# the tracked tree in a 64 MiB transfer) in the ignored folders .gpu0, .gpu1, ... of the
# checkout, one part each. On the machine, carry one folder a call and copy its part out
#   mkdir -p /tmp/w && cp .gpuN/* /tmp/w/
# then, in the call that carries the last one, unpack and run:
#   mkdir -p /tmp/site && cat /tmp/w/part.* | xz -dc -T0 | tar -C /tmp/site -xf - &&
#   PYTHONPATH=/tmp/site bash tools/gpu_check.sh /tmp/gc
# (2026-12-04: 2 parts with policies/runs out of the tree, 3 with it).
set -euo pipefail
cd "$(dirname "$0")/.."
tree_mb=$(git ls-files -z | xargs -0 du -cb | tail -1 | awk '{print int($1 / 1e6) + 1}')
part_mb=${1:-$((64 * 1048576 / 1000000 - tree_mb - 2))}
if ((part_mb < 8)); then
  echo "gpu_site: the tracked tree ($tree_mb MB) leaves no room for parts in 64 MiB" >&2
  exit 2
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
  --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d "$work/whl" \
  warp-lang==1.19.0 mujoco-warp==4.0.0 mujoco==4.0.1 mujoco-core==4.0.1
mkdir "$work/site"
python3 - "$work" <<'EOF'
import pathlib, sys, zipfile
work = pathlib.Path(sys.argv[1])
for wheel in sorted((work / "whl").glob("*.whl")):
    with zipfile.ZipFile(wheel) as z:
        for name in z.namelist():
            if name == "warp/bin/warp-clang.so" or name.startswith("warp/examples/"):
                continue
            z.extract(name, work / "site")
EOF
tar -C "$work/site" -cf - . | xz -T0 -6 >"$work/site.tar.xz"
rm -rf .gpu[0-9]*
split -b "${part_mb}000000" -d "$work/site.tar.xz" "$work/part."
i=0
for part in "$work"/part.*; do
  mkdir -p ".gpu$i" && mv "$part" ".gpu$i/"
  i=$((i + 1))
done
grep -qx '/.gpu\*/' .git/info/exclude 2>/dev/null || echo '/.gpu*/' >>.git/info/exclude
echo "gpu_site: $(du -b "$work/site.tar.xz" | cut -f1) bytes in $i parts of at most $part_mb MB: .gpu0 .. .gpu$((i - 1))"

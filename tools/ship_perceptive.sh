#!/usr/bin/env bash
# Ship a perceptive checkpoint: every figure of its policy card, in one unattended, resumable run.
#
#   bash tools/ship_perceptive.sh CKPT [OUT]      # OUT defaults to policies/perceptive
#
# Copies CKPT to policies/tron1_perceptive.pt, exports and checks policies/tron1_perceptive.onnx,
# then writes under OUT: Table I at the hardest level (the student as deployed, i.e. the ONNX;
# its teacher; the blind flat policy), the climb probe, Fig. 5 (success by commanded speed per
# velocity dimension), Fig. 6 (pushes: moderate on the four complex terrains, extreme on flat),
# deploy-sim of the ONNX on the hardest stairs up with the 30 Hz depth thread (video, rerun
# recording, JSON), the campaign's curves and the card's tables in Markdown (OUT/tables.md). A
# step whose output is already there is skipped, so a killed run goes on where it stopped; delete
# a step's folder to redo it.
#
# Environment: ENVS (Table I and pushes, default 1024, as the paper), FIG_ENVS (Fig. 5, default
# 256), CLIMB_ENVS (the climb probe, default 128), STEPS (default 500 = 10 s), SEED (of every
# evaluation, default 1: the checkpoint was picked by evaluations with seed 0, so the shipped
# figures come from envs the choice never saw), RUN (the campaign's run directory, for the
# curves), DEPLOY_RUNS (deploy-sim runs on the hardest stairs, default 50), SHIP_TO (the shipped
# files without extension, default policies/tron1_perceptive). On
# two cores the whole run should take about 90 minutes (estimated from single evaluations: the
# student on 1024 envs x 500 steps takes about 4 minutes a terrain); nothing else should run
# beside it.
set -euo pipefail

ckpt=${1:?usage: bash tools/ship_perceptive.sh CKPT [OUT]}
out=${2:-policies/perceptive}
envs=${ENVS:-1024}
fig_envs=${FIG_ENVS:-256}
steps=${STEPS:-500}
seed=${SEED:-1}
run=${RUN:-policies/runs/cts_phase2}
pt=${SHIP_TO:-policies/tron1_perceptive}.pt
onnx=${SHIP_TO:-policies/tron1_perceptive}.onnx
mkdir -p "$out"

step() {  # step NAME DONE-FILE COMMAND...: run COMMAND unless DONE-FILE exists; log to OUT/NAME.log
    local name=$1 done=$2
    shift 2
    if [[ -e $done ]]; then
        echo "skip  $name ($done exists)"
        return
    fi
    echo "run   $name"
    "$@" >"$out/$name.log" 2>&1 || { echo "FAILED $name: see $out/$name.log" >&2; exit 1; }
}

[[ -f $ckpt ]] || { echo "error: $ckpt: no such checkpoint" >&2; exit 1; }
if [[ ! -e $pt ]]; then
    cp "$ckpt" "$pt"
elif ! cmp -s "$ckpt" "$pt"; then  # a resumed run must not go on with another checkpoint's files
    echo "error: $pt is another checkpoint than $ckpt; move it, its .onnx and $out away to ship this one" >&2
    exit 1
fi
step export "$onnx" tron1 export-onnx "$pt" -o "$onnx"
common=(--envs "$envs" --steps "$steps" --seed "$seed")
step table1_student "$out/table1_student/results.json" \
    tron1 eval student="$onnx" --terrain all "${common[@]}" --out "$out/table1_student"
step table1_teacher "$out/table1_teacher/results.json" \
    tron1 eval teacher="$pt" --actor teacher --terrain all "${common[@]}" --out "$out/table1_teacher"
step table1_blind "$out/table1_blind/results.json" \
    tron1 eval blind_flat=policies/tron1_flat.pt --terrain all "${common[@]}" --out "$out/table1_blind"
step climb "$out/climb/climb.json" \
    tron1 eval "$pt" --climb --envs "${CLIMB_ENVS:-128}" --steps "$steps" --seed "$seed" --out "$out/climb"
for terrain in stairs slopes discrete rough flat; do
    speeds=(--speeds vx:0.25,0.5,0.75,1.0)
    # stairs and slopes command the climb (forward, no sideways speed): vx and yaw only there
    [[ $terrain == stairs || $terrain == slopes ]] || speeds+=(--speeds vy:0.25,0.5)
    speeds+=(--speeds yaw:0.25,0.5)
    step "fig5_$terrain" "$out/fig5_$terrain/results.json" \
        tron1 eval student="$onnx" --terrain "$terrain" --envs "$fig_envs" --steps "$steps" --seed "$seed" \
        "${speeds[@]}" --metrics success_rate,command_progress --out "$out/fig5_$terrain"
done
for terrain in stairs slopes discrete rough; do
    step "push_moderate_$terrain" "$out/push_moderate_$terrain/results.json" \
        tron1 push-test "$onnx" --terrain "$terrain" --envs "$envs" --seed "$seed" \
            --out "$out/push_moderate_$terrain"
done
step push_extreme_flat "$out/push_extreme_flat/results.json" \
    tron1 push-test "$onnx" --extreme --terrain flat --envs "$envs" --seed "$seed" --out "$out/push_extreme_flat"
# the figures (survival, real-time factor, depth rate) from DEPLOY_RUNS plain runs, seeds 0 (the
# default run's) upward: one run is an anecdote; the video and the rerun recording from the
# default run again, since recording slows the loop
deploy=(tron1 deploy-sim "$onnx" --terrain stairs_up --level 9 --cmd 0.5,0,0 --duration 10)
step deploy_sim "$out/deploy_sim_stairs.json" \
    bash -c '"$@" --json > "$0.tmp" && mv "$0.tmp" "$0"' "$out/deploy_sim_stairs.json" "${deploy[@]}" \
    --runs "${DEPLOY_RUNS:-50}"
step deploy_sim_recorded "$out/deploy_sim_stairs.mp4" \
    "${deploy[@]}" --video "$out/deploy_sim_stairs.mp4" --rerun save="$out/deploy_sim_stairs.rrd"
step curves "$out/curves.png" tron1 report "$run" --png "$out/curves.png" --x env_steps
python "$(dirname "$0")/card_tables.py" "$out" >/dev/null  # the card's tables, from all of the above
echo "shipped: $pt, $onnx; figures under $out (the card's tables: $out/tables.md)"
echo "look at $out/deploy_sim_stairs.mp4 before saying it climbs"

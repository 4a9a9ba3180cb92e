"""Which of the student's estimates keeps it from climbing? The climb probe with latents swapped.

A lab tool, not a ``tron1`` command. One checkpoint's shared policy walks the climb probe
(:mod:`tron1cli.evaluation.climb`: stairs up, full window, training commands and randomisation)
five times, acting on

- ``student``: its own estimates, l^{s,e} (proprioceptive history) and l^{s,h} (depth + GRU);
- ``student+true_h``: l^{s,e} and the teacher's heightmap latent l^{t,h} (the true h_t encoded);
- ``student+true_e``: the teacher's privileged latent l^{t,e} and l^{s,h};
- ``teacher``: both teacher latents (the probe's teacher row);
- ``student+reencoded_h``: l^{s,e} and the teacher encoder's latent of the student's own
  reconstruction, enc^{t,h}(h_hat) (what ``--learner reencode_h=true`` trains with).

Every variant reads o_t from the student's history and keeps the student's camera on, so the rows
differ only in the latents. A student that climbs once given l^{t,h} is held back by its image
path; one that climbs once given l^{t,e} by its privileged estimate. ``--terrain`` asks the same
of another terrain type (risers are counted on stairs up only):

    python tools/latent_swap.py policies/runs/cts_phase1/checkpoints/latest.pt --levels 6 9
    python tools/latent_swap.py policies/runs/cts_phase1/checkpoints/latest.pt --terrain discrete --levels 9
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, replace

import numpy as np
import torch

from tron1cli.env.terrain import riser_m
from tron1cli.evaluation.climb import CLIMB_ENVS, CLIMB_LEVELS, CLIMB_TERRAIN, risers_climbed
from tron1cli.evaluation.protocol import EvalSpec, run_batch
from tron1cli.policy.runtime import Policy, load_policy

#: variant -> (act on the teacher's l^e, the heightmap latent: "own" (the checkpoint student's),
#: "true" (the teacher's) or "reencoded" (enc^{t,h} of the student's reconstruction))
VARIANTS = {
    "student": (False, "own"),
    "student+true_h": (False, "true"),
    "student+true_e": (True, "own"),
    "teacher": (True, "true"),
    "student+reencoded_h": (False, "reencoded"),
}


@dataclass
class SwappedPolicy(Policy):
    """A checkpoint's student whose action reads the teacher's privileged latent where ``true_e``
    says so and the heightmap latent ``h_latent`` names (see :data:`VARIANTS`; the GRU still
    advances on every frame)."""

    model: torch.nn.Module | None = None
    true_e: bool = False
    h_latent: str = "own"

    @property
    def actor(self) -> str:
        return "student"  # the env keeps the camera on

    def act(
        self, obs: dict[str, np.ndarray], hidden: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        m = self.model
        raw = {
            k: torch.from_numpy(np.asarray(obs[k], dtype=np.float32))
            for k in ("history", "privileged", "heightmap")
        }
        raw["proprio"] = raw["history"][:, -m.dims.proprio :]  # o_t as the student reads it
        with torch.no_grad():
            ob = m.normalize(raw)
            depth = torch.from_numpy(self.depth_input(obs, len(hidden)))
            le_s = m.student_latent_e(ob["history"])
            lh_gru, hidden_next = m.est_h.step(ob["history"], depth, torch.from_numpy(hidden))
            le_t, lh_t = m.teacher_latents(ob["privileged"], ob["heightmap"])
            le = le_t if self.true_e else le_s
            if self.h_latent == "true":
                lh = lh_t
            elif self.h_latent == "reencoded":
                lh = m.reencoded_h(lh_gru)
            else:
                lh = m.policy_h_latent(lh_gru)
            action = m.action_mean(ob["proprio"], le, lh).numpy()
        return action, hidden_next.numpy(), np.zeros((len(action), 0), dtype=np.float32)


def swapped(path: str, true_e: bool = False, h_latent: str = "own") -> SwappedPolicy:
    """The student of checkpoint ``path`` acting on the latents ``true_e`` / ``h_latent`` say."""
    student = load_policy(path, actor="student")
    model = load_policy(path, actor="teacher")._teacher  # the whole VisionCTS, eval mode
    return SwappedPolicy(
        student.path,
        student.kind,
        student.contract,
        student.run_cfg,
        model=model,
        true_e=true_e,
        h_latent=h_latent,
    )


def swap_row(policy: SwappedPolicy, spec: EvalSpec) -> tuple[float, float, float | None, float | None]:
    """(success, traverse, command progress, risers per env or None off stairs up) of one batch."""
    r = run_batch(policy, spec)
    m = r.metrics
    risers = None
    if spec.terrain == CLIMB_TERRAIN:
        risers = risers_climbed(r.rise_m, riser_m(policy.run_cfg.env.terrain_cfg, spec.level))
    return float(m["success_rate"]), float(m["traverse_rate"]), m["command_progress"], risers


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--terrain", default=CLIMB_TERRAIN, help="one terrain type (default: stairs_up)")
    ap.add_argument("--levels", type=int, nargs="+", default=list(CLIMB_LEVELS))
    ap.add_argument("--envs", type=int, default=CLIMB_ENVS)
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(f"{args.terrain}: variant | level | success % | traverse % | progress | risers")
    own = swapped(args.checkpoint)  # the checkpoint read once; the variants differ in two flags
    for name, (true_e, h_latent) in VARIANTS.items():
        policy = replace(own, true_e=true_e, h_latent=h_latent)
        for level in args.levels:
            spec = EvalSpec(args.terrain, level, args.envs, args.steps, True, seed=args.seed)
            success, traverse, progress, risers = swap_row(policy, spec)
            text = [f"{100 * success:.1f}", f"{100 * traverse:.1f}"]
            text += ["-" if v is None else f"{v:.2f}" for v in (progress, risers)]
            print(f"{name} | {level} | " + " | ".join(text), flush=True)


if __name__ == "__main__":
    main()

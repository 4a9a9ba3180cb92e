"""How much memory an env count needs, checked before any env is built.

The figures are lower bounds, counted from the arrays the code allocates for every env (measured
with tracemalloc on this code: 9-10 KiB an env of a blind env on flat ground, 50-68 KiB with the
heightmap and a depth camera on stairs), so a count is refused only when the machine cannot hold
even those: ``--envs 100000000`` is refused at once instead of allocating for half a minute and
dying in numpy, while the sizes runs use (1024-4096 envs: tens to a few hundred MiB) always pass.
"""

from __future__ import annotations

from pathlib import Path

from tron1cli.errors import UsageError

KIB = 1024
#: numpy arrays of every env (physics state, substep trajectories, sensors, observations, rewards)
ENV_BYTES = 8 * KIB
#: an env with perception: the 441-point height scan and its buffers
PERCEPTION_BYTES = 4 * KIB
#: an env that renders depth: at least one 60 x 80 float32 frame held
DEPTH_BYTES = 60 * 80 * 4


def env_bytes(cfg, model_bytes: int = 0) -> int:
    """Bytes at least an env of EnvConfig ``cfg`` needs (the mean over its envs): its arrays, plus
    ``model_bytes`` for a world of its own (an MjModel copy per env)."""
    n = max(int(cfg.num_envs), 1)
    per = ENV_BYTES + model_bytes
    if cfg.perception:
        depth_envs = max(n - int(cfg.depth_from), 0)
        per += PERCEPTION_BYTES + DEPTH_BYTES * depth_envs // n
    return per


def rollout_bytes(sizes: dict[str, int], steps: int, action_dim: int = 6, groups: int = 2) -> int:
    """Bytes at least a learner's rollout storage needs per env: float32 observation groups
    (``sizes``: proprio, history, privileged, heightmap), actions, means and sigmas, values,
    rewards, returns and advantages per reward group, for ``steps`` steps."""
    floats = sum(int(sizes.get(k, 0)) for k in ("proprio", "history", "privileged", "heightmap"))
    floats += 3 * action_dim + 4 * groups + 3
    return 4 * steps * floats


def _read_int(path: str) -> int | None:
    try:
        text = Path(path).read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def available_bytes() -> int | None:
    """Memory this process can still take: MemAvailable of /proc/meminfo, or less under a cgroup
    (v2) memory limit; None where neither can be read."""
    avail = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = int(line.split()[1]) * KIB
                break
    except (OSError, ValueError, IndexError):
        pass
    limit, used = _read_int("/sys/fs/cgroup/memory.max"), _read_int("/sys/fs/cgroup/memory.current")
    if limit is not None and used is not None:
        avail = limit - used if avail is None else min(avail, limit - used)
    return avail


def _size(n: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


def check_memory(num_envs: int, per_env: int, what: str = "envs", option: str = "--envs") -> None:
    """Refuse (:class:`UsageError`, exit 2) ``num_envs`` envs of ``per_env`` bytes each when the
    machine has less memory available; nothing where the available memory is unknown."""
    avail = available_bytes()
    need = int(num_envs) * int(per_env)
    if avail is None or need <= avail:
        return
    fit = max(avail // max(per_env, 1), 0)
    raise UsageError(
        f"{option} {num_envs:,}: {what} need at least {_size(need)} of memory ({_size(per_env)} an env), "
        f"more than the {_size(avail)} this machine has available; {fit:,} envs or fewer fit"
    )

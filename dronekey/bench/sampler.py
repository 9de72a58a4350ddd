"""``dronekey-bench sampler``: how fast the training sampler renders crops.

Training draws every crop fresh from ``sim_replay.sampler.CropSampler`` in DataLoader workers, so
its rate per core bounds the training throughput: the trainer needs ``batch / step time`` crops per
second. Timed in this process on one core: wall-clock rate, and CPU time per sample (the figure
least disturbed by other load).
"""

from __future__ import annotations

import argparse
import json
import time

from dronekey.bench.arguments import positive_int

__all__ = ["add_sampler_command", "time_sampler"]


def time_sampler(samples: int, seed: int = 0, warmup: int = 20) -> dict:
    """Render ``samples`` crops after ``warmup`` untimed ones; rates and the share with a drone."""
    # Imported when timed, not when registered: every dronekey-bench process registers this command,
    # and the daemon's benchmarks report the process's resident memory.
    from dronekey.sim_replay.sampler import CropSampler

    sampler = CropSampler(seed=seed)
    for _ in range(warmup):  # fills the background pool, which is then refreshed one at a time
        sampler.sample()
    present = 0
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(samples):
        present += sampler.sample().present
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return {
        "samples": samples,
        "input": [sampler.config.crop.input_size] * 2,
        "samples_per_s": round(samples / wall, 1),
        "cpu_ms_per_sample": round(1000 * cpu / samples, 2),
        "samples_per_cpu_s": round(samples / cpu, 1),
        "with_drone": round(present / samples, 3),
    }


def _run(args: argparse.Namespace) -> int:
    result = time_sampler(args.samples, args.seed)
    if args.json:
        print(json.dumps(result))
    else:
        print(
            f"{result['samples']} crops of {result['input'][0]} px: {result['samples_per_s']} samples/s, "
            f"{result['cpu_ms_per_sample']} ms CPU per sample ({result['samples_per_cpu_s']} per CPU second)"
        )
    return 0


def add_sampler_command(subparsers) -> None:
    """Register ``sampler``: rendered training crops per second on one core."""
    parser = subparsers.add_parser(
        "sampler",
        help="training crops rendered per second (one core)",
        description="Time the training sampler (sim_replay.sampler.CropSampler) on one core: rendered "
        "128 px crops per second, and CPU milliseconds per crop (least disturbed by other load). "
        "Training needs batch / step-time crops per second from its DataLoader workers.",
    )
    parser.add_argument("--samples", type=positive_int, default=500, help="timed samples (default 500)")
    parser.add_argument("--seed", type=int, default=0, help="sampler seed (default 0)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a line")
    parser.set_defaults(handler=_run)

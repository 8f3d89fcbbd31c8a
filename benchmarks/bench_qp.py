"""Speed of one compensation QP (issue 3): the structured solver against OSQP at equal accuracy.

    python benchmarks/bench_qp.py [--problems 200] [--noise realistic]

QPs (K = 650) are built from the selected segments of a simulated one-hour drive, linearised with
a step-1-like parameter set (batch G-N on ten segments). Each is solved cold by the structured
solver and by OSQP; OSQP counts as solved only once its polished answer is feasible to 1e-9, and
its time is that of all the attempts this took. Both objectives are compared.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import odocal
from odocal.data.segments import gather, identification_segments
from odocal.estimators.compensation import STATUS_NAMES, build_problem, solve_qp
from odocal.estimators.compensation.reference import solve_osqp
from odocal.estimators.gauss_newton import gauss_newton
from odocal.model.parameters import Inputs
from odocal.settings import Settings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", type=int, default=200)
    parser.add_argument("--noise", default="realistic")
    args = parser.parse_args()
    settings = Settings()
    sim = odocal.simulate(duration_s=3600, seed=7, noise=args.noise)
    segs = identification_segments([sim.drive], settings.segments)
    batch = gather([sim.drive], segs.subset(segs.selected))
    theta = gauss_newton(batch.take(np.arange(0, len(batch), len(batch) // 10)[:10]),
                         settings=settings.identify).theta.as_array()
    picks = np.linspace(0, len(batch) - 1, min(args.problems, len(batch))).astype(int)
    solve_qp(build_problem(theta, Inputs(*(getattr(batch.inputs, f)[0] for f in
                                           ("n_rl", "n_rr", "beta", "a_y"))),
                           batch.reference[0], batch.t_s, settings.compensate),
             settings.compensate)                        # compile the kernels first
    fast, ref, ratio, rel, iters, active = [], [], [], [], [], []
    paths: dict[str, int] = {}
    unsolved = 0
    for i in picks:
        u = Inputs(*(getattr(batch.inputs, f)[i] for f in ("n_rl", "n_rr", "beta", "a_y")))
        p = build_problem(theta, u, batch.reference[i], batch.t_s, settings.compensate)
        t0 = time.perf_counter()
        ours = solve_qp(p, settings.compensate)
        t1 = time.perf_counter()
        osqp = solve_osqp(p)
        t2 = time.perf_counter()
        paths[STATUS_NAMES[ours.status]] = paths.get(STATUS_NAMES[ours.status], 0) + 1
        if not osqp.solved:
            unsolved += 1
            continue
        fast.append(t1 - t0)
        ref.append(t2 - t1)
        ratio.append((t2 - t1) / (t1 - t0))
        iters.append(ours.iterations)
        f_ref = p.objective(osqp.z)
        rel.append(abs(ours.objective - f_ref) / abs(f_ref))
        z = ours.z.reshape(p.steps, 5)
        active.append(int(np.sum(np.isclose(z, p.lower, atol=1e-12)
                                 | np.isclose(z, p.upper, atol=1e-12))))
    print(f"{len(picks)} QPs, K = {batch.steps}, noise '{args.noise}'; solver paths {paths}; "
          f"OSQP could not reach a feasible polished answer on {unsolved}")
    print(f"structured solver: median {statistics.median(fast) * 1e3:.2f} ms, "
          f"p90 {np.percentile(fast, 90) * 1e3:.2f} ms, max {max(fast) * 1e3:.2f} ms; "
          f"median {statistics.median(iters):.0f} active-set iterations, "
          f"median {statistics.median(active):.0f} active bounds")
    print(f"OSQP (polished, feasible to 1e-9): median {statistics.median(ref) * 1e3:.1f} ms, "
          f"p90 {np.percentile(ref, 90) * 1e3:.1f} ms")
    print(f"speed-up: ratio of medians {statistics.median(ref) / statistics.median(fast):.0f}x, "
          f"median per-problem ratio {statistics.median(ratio):.0f}x, "
          f"smallest {min(ratio):.0f}x")
    print(f"objective agreement: largest relative difference {max(rel):.1e} "
          f"(median {statistics.median(rel):.1e})")


if __name__ == "__main__":
    main()

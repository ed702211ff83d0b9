"""Throughput of the JAX/diffrax reverse-mode peer (``grad_peer`` of
``jax_sensitivities.py`` in the peers' folder) on hamgrav's own arcs: the arcs' initial states
and sample grid exported by ``bench/gradient.py --export-peer``, the peer's network (721
parameters), dynamics and loss, its Dopri8 at ``--rtol``. Runs in the peers' environment (JAX,
diffrax; see their README), not hamgrav's. Prints the best of ``--repeat`` calls after one that
compiles, in arcs/s.

    PEERS=../shared/peers peer/bin/python bench/peer_gradient.py arcs.npz [--rtol 1e-10]
        [--repeat 7]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("arcs", help="npz from bench/gradient.py --export-peer")
    parser.add_argument("--rtol", type=float, default=1e-10)
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()
    sys.path.insert(0, os.environ.get("PEERS", os.path.join("..", "shared", "peers")))
    import diffrax
    import jax
    import jax.numpy as jnp
    import jax_sensitivities as peer

    data = np.load(args.arcs, allow_pickle=False)
    x0s = jnp.asarray(data["states0"])
    # the peer integrates every arc on one grid from 0: the arcs' mean span, 40 samples
    span = float(np.mean(data["times"][:, -1] - data["times"][:, 0]))
    ts = jnp.linspace(0.0, span, data["times"].shape[1])
    rng = np.random.default_rng(0)
    th = jnp.asarray(rng.normal(size=peer.NP) * 0.3)

    def arc(th, x0):
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(peer.f), diffrax.Dopri8(), 0.0, ts[-1], None, x0, args=th,
            saveat=diffrax.SaveAt(ts=ts),
            stepsize_controller=diffrax.PIDController(rtol=args.rtol, atol=args.rtol),
            max_steps=10000,
        )  # fmt: skip
        return sol.ys

    def loss(th, x0s):
        return 0.5 * jnp.sum((jax.vmap(arc, in_axes=(None, 0))(th, x0s) - 1.0) ** 2)

    grad = jax.jit(jax.grad(loss))
    grad(th, x0s).block_until_ready()
    best = np.inf
    for _ in range(args.repeat):
        start = time.perf_counter()
        grad(th, x0s).block_until_ready()
        best = min(best, time.perf_counter() - start)
    print(
        f"jax-diffrax reverse mode, {len(x0s)} arcs x {len(ts)} samples, rtol {args.rtol:g}, "
        f"{peer.NP} parameters: {len(x0s) / best:.0f} arcs/s (best of {args.repeat})"
    )


if __name__ == "__main__":
    main()

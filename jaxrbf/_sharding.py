"""Spreading work over every JAX device (several GPUs, or several hosts under `jax.distributed`).

Everything here is a no-op on a single device. With several, batched work (the patch fits of
the partition-of-unity method, and blocks of query points in model evaluation, hence grid
sampling and meshing) is split along a one-axis device mesh with `shard_map`: each device
works on its own share of the rows, with no communication until the results are joined.
Batch sizes are rounded up to a multiple of the device count (`pad_to_devices`).

Several hosts: start every process with `jax.distributed.initialize()` before calling jaxrbf;
`jax.devices()` then lists every host's devices and the same mesh spans them.

To test on a CPU: `XLA_FLAGS=--xla_force_host_platform_device_count=4` before importing JAX.
"""

from __future__ import annotations

import jax
import numpy as np
from jax.sharding import Mesh, PartitionSpec

AXIS = "devices"


def n_devices() -> int:
    return jax.device_count()


def device_mesh() -> Mesh:
    return Mesh(np.array(jax.devices()), (AXIS,))


def pad_to_devices(size: int) -> int:
    """`size` rounded up to a multiple of the device count."""
    k = n_devices()
    return -(-size // k) * k


def sharded_rows(fn, *xs):
    """`fn(*xs)` for a row-wise `fn` (each of `xs` is (n, ...), and so is each output), with the
    rows split over all devices (`shard_map`: each device runs `fn` on its own rows, with no
    communication; whatever `fn` closes over is replicated). Single device: `fn(*xs)`.

    Used by model evaluation (query points, and so grid sampling and meshing) and the batched
    patch fits, so several devices share each of them with no change to the caller.

    Not used inside the CG/GMRES loops of the dense path: a `shard_map` kernel product inside
    lineax's while loops deadlocked on simulated CPU devices (with or without an in-map
    all_gather), so those matrix-free products run on one device."""
    k = n_devices()
    if k == 1:
        return fn(*xs)
    import jax.numpy as jnp

    n = xs[0].shape[0]
    pad = (-n) % k

    def padded(x):
        x = jnp.asarray(x)
        return jnp.concatenate([x, jnp.broadcast_to(x[:1], (pad,) + x.shape[1:])]) if pad else x

    spec = PartitionSpec(AXIS)
    out = jax.shard_map(
        fn, mesh=device_mesh(), in_specs=(spec,) * len(xs), out_specs=spec, check_vma=False
    )(*(padded(x) for x in xs))
    return jax.tree.map(lambda o: o[:n], out)

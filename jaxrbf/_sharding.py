"""Spreading work over every JAX device (several GPUs, or several hosts under `jax.distributed`).

Everything here is a no-op on a single device. With several, batched work (the patch fits of
the partition-of-unity method, and model evaluation and gradients called on concrete points) is
split into one share per device: each device works on its own rows, with no communication, and
the results are joined on the host. Evaluation traced inside another jit-compiled function runs
on one device.

Several hosts (`jax.distributed`): a process can only place arrays on its own devices, so each
process splits its work over `jax.local_devices()`; spreading one fit over several hosts means
giving each process its own part of the input.

To test on a CPU: `XLA_FLAGS=--xla_force_host_platform_device_count=4` before importing JAX.
"""

from __future__ import annotations

import jax
import numpy as np


def n_devices() -> int:
    return jax.local_device_count()


def pad_to_devices(size: int) -> int:
    """`size` rounded up to a multiple of the device count."""
    k = n_devices()
    return -(-size // k) * k


def split_over_devices(fn, *arrays):
    """`fn(*arrays)` for a row-wise `fn` (every input and output has the same leading length),
    computed as one contiguous share of the rows per device, then joined on the host (numpy).

    The shares are placed with `jax.device_put` and `fn` (jit-compiled) is dispatched to every
    device before any result is read, so the devices work at the same time; nothing is
    communicated between them. The rows are padded to a multiple of the device count, so every
    share has the same shape (one compilation). Single device: `fn(*arrays)`, as numpy.

    (A first version used `shard_map` inside the jit-compiled functions: on simulated CPU devices
    its result resharding deadlocked at random, about one run in three, inside and outside
    lineax's loops; host-level shares need no collective at all.)"""
    k = n_devices()
    if k == 1:
        return jax.tree.map(np.asarray, fn(*arrays))
    n = len(arrays[0])
    size = -(-n // k)

    def share(x, i):
        part = np.asarray(x[i * size : (i + 1) * size])
        if len(part) < size:
            fill = np.broadcast_to(np.asarray(x[:1]), (size - len(part),) + part.shape[1:])
            part = np.concatenate([part, fill]) if len(part) else np.array(fill)
        return part

    outs = [
        fn(*(jax.device_put(share(x, i), dev) for x in arrays))
        for i, dev in enumerate(jax.local_devices())
    ]
    joined = jax.tree.map(lambda *parts: np.concatenate([np.asarray(p) for p in parts]), *outs)
    return jax.tree.map(lambda a: a[:n], joined)

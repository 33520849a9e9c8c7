"""Spreading work over every JAX device (several GPUs, or several hosts under `jax.distributed`).

Everything here is a no-op on a single device. With several, batched work (patch fits, blocks of
query points, blocks of kernel-matrix rows) is laid out along a one-axis device mesh: the leading
axis of each batch is split across the devices and jit-compiled code runs on each device's share
(XLA's SPMD partitioner inserts the few collectives needed). Batch sizes are rounded up to a
multiple of the device count by the callers (`pad_to_devices`).

To test on a CPU: `XLA_FLAGS=--xla_force_host_platform_device_count=4` before importing JAX.
"""

from __future__ import annotations

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "devices"


def n_devices() -> int:
    return jax.device_count()


def device_mesh() -> Mesh:
    return Mesh(np.array(jax.devices()), (AXIS,))


def pad_to_devices(size: int) -> int:
    """`size` rounded up to a multiple of the device count."""
    k = n_devices()
    return -(-size // k) * k


def shard_leading(*arrays):
    """Place each array with its leading axis split over all devices (replicated elsewhere).
    Single device: the arrays as they are. The leading sizes must be multiples of the device
    count."""
    if n_devices() == 1:
        return arrays
    sharding = NamedSharding(device_mesh(), PartitionSpec(AXIS))
    return tuple(jax.device_put(a, sharding) for a in arrays)

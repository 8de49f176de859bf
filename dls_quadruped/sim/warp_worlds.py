"""MuJoCo Warp's N worlds on one device: the model and data the Warp backend (``sim/warp_backend.py``) steps.

:class:`WarpWorlds` puts the host ``mujoco.MjModel`` on the device once (``mujoco_warp.put_model``) with
``nworld = N`` worlds in one ``Data``, installs the terrain culling (``sim/warp_collision.py``), wraps the
two step phases, ``forward`` and the masked ``reset_data`` in captured graphs (``sim/warp_graph.py``) and holds
``warp.to_torch`` views (zero-copy) of the arrays the backend reads and writes every physics step. Per-robot model
values (``geom_friction``, ``body_mass``, any field MuJoCo Warp can batch) become ``(N, ...)`` arrays the first time one
is written, shared ``(1, ...)`` arrays until then. A snapshot's part of the simulation is :data:`WARP_STATE_FIELDS`
plus those per-robot fields.
"""

from __future__ import annotations

import dataclasses
from contextlib import ExitStack
from typing import Any

import mujoco
import numpy as np
import torch
import warp as wp

wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)  # no banner, no module-load lines

import mujoco_warp as mjw

from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.interface import SimConfig
from dls_quadruped.sim.warp_collision import CELL, TerrainCulling
from dls_quadruped.sim.warp_graph import StepGraph

WARP_STATE_FIELDS = ("time", "qpos", "qvel", "act", "history", "qacc_warmstart", "ctrl", "qfrc_applied",
                     "xfrc_applied", "eq_active", "mocap_pos", "mocap_quat", "userdata", "plastic")
"""MuJoCo Warp ``Data`` fields that ``step1``/``step2`` read without computing them (MuJoCo's integration
state, ``shard.MJ_STATE_FIELDS``): a snapshot's part of the simulation."""


def warp_device_for(name: str) -> str:
    """The Warp device of a backend device name (``cpu`` or ``cuda``/``cuda:k``), checked.

    Raises:
        RuntimeError: ``cuda`` without a CUDA device for Warp, or without a CUDA build of torch (one line).
    """
    if name == "cpu":
        return "cpu"
    if not name.startswith("cuda"):
        raise ValueError(f"Warp backend device must be 'cpu' or 'cuda[:k]', got {name!r}")
    wp.init()
    if wp.get_cuda_device_count() == 0:
        raise RuntimeError("simulator backend 'cuda' needs a CUDA GPU and driver, and Warp found none; "
                           "use scene.backend: warp-cpu (or cpu) on this machine")
    if not torch.cuda.is_available():
        raise RuntimeError("simulator backend 'cuda' needs a CUDA build of torch (torch.cuda.is_available() is "
                           "False); install one (https://pytorch.org/get-started/locally/), then pip install -e .[gpu]")
    # plain "cuda": torch's current device (torchrun's ranks set theirs, learning/distributed.py)
    return f"cuda:{torch.cuda.current_device()}" if name == "cuda" else name


def csr_pairs(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """(row, column) of each element of the CSR inertia ``M`` (MuJoCo Warp's ``d.M``, the model's CSR layout)."""
    rows = np.repeat(np.arange(model.nv), model.M_rownnz)
    return rows, np.asarray(model.M_colind)


def publish_contacts(sensordata: torch.Tensor, slices: dict[str, slice], foot_force_w: torch.Tensor,
                     base_contact: torch.Tensor) -> None:
    """Write (N, 4, 3) foot reaction forces [N] and the (N,) trunk/thigh contact flag from the contact sensors'
    (N, S) values (``slices``: sensor name -> its columns), in place."""
    for i, leg in enumerate(C.LEG_NAMES):
        # the netforce sensor reports the foot's force on the ground: negate for the reaction
        sl = slices[f"{leg}_foot_contact"]
        foot_force_w[:, i] = -sensordata[:, sl.start + 1: sl.stop]
    body = sensordata[:, slices["trunk_contact"].start] > 0
    for leg in C.LEG_NAMES:
        body |= sensordata[:, slices[f"{leg}_thigh_contact"].start] > 0
    base_contact.copy_(body)


class WarpWorlds:
    """The N worlds of one MuJoCo Warp model on one device, with torch views of the arrays the backend uses.

    Args:
        model: the host scene (one robot and the ground).
        num_envs: number of worlds N.
        cfg: ``nconmax``, ``njmax`` (allocations per world) and ``regions`` (terrain culling) apply.
        wp_device: Warp device (:func:`warp_device_for`).
        base_body: the robot's base body id (terrain culling's cell lookup).
        capture: replay the step phases from captured graphs.

    Attributes (torch views, rows = worlds): ``qpos`` (N, nq), ``qvel`` (N, nv), ``time`` (N,), ``ctrl``
    (N, nu), ``xfrc`` (N, nbody, 6), ``sensordata`` (N, nsensordata), ``M`` (N, 1, nM) CSR, ``qfrc_bias``
    (N, nv), ``qacc_warmstart`` (N, nv), ``overflow`` (N,) MuJoCo Warp's per-world overflow bits.
    """

    def __init__(self, model: mujoco.MjModel, num_envs: int, cfg: SimConfig, wp_device: str, base_body: int,
                 capture: bool = True):
        self.num_envs = num_envs
        self.wp_device = wp_device
        self.device = torch.device(wp_device)
        self.capture_stream: Any = None
        """The ``wp.Stream`` an outer capture records on (:meth:`launch_directly`), else None."""
        with self.scope():
            self.m = mjw.put_model(model)
            self.d = mjw.make_data(model, nworld=num_envs, nconmax=cfg.nconmax, njmax=cfg.njmax)
            # overflows are flagged per robot and reported once by the backend, not printed by MuJoCo Warp's
            # kernels at every step
            self.m.opt.warn_overflow = 0
            self.culling = None if cfg.regions is None else TerrainCulling(
                model, self.m, self.d.naconmax, base_body, cfg.regions.cell or CELL, cfg.regions.margin)
        # the physics step's two phases, replayed from captured Warp graphs (sim/warp_graph.py); so are a reset's
        # reset_data (of the worlds in reset_mask, a buffer the graph reads in place) and forward, and the step1
        # a push or a model-field change runs: one graph launch each instead of ~60-125 kernel launches
        self.step1 = StepGraph(mjw.step1, self.m, self.d, wp_device, enabled=capture)
        self.step2 = StepGraph(mjw.step2, self.m, self.d, wp_device, enabled=capture)
        self.forward = StepGraph(mjw.forward, self.m, self.d, wp_device, enabled=capture)
        self.reset_mask = torch.zeros(num_envs, dtype=torch.bool, device=self.device)
        """Which worlds :attr:`reset_data` resets (written in place before each call)."""
        mask = wp.from_torch(self.reset_mask)

        def reset_data(m: Any, d: Any) -> None:
            mjw.reset_data(m, d, reset=mask)

        self.reset_data = StepGraph(reset_data, self.m, self.d, wp_device, enabled=capture)
        self.graphs = (self.step1, self.step2, self.forward, self.reset_data)
        self.batched: set[str] = set()
        """The model fields made per-world so far."""
        self.generation = 0
        """Bumped whenever an array a captured graph reads is replaced (an outer capture, ``envs/env_graph.py``,
        captures again when it changed)."""
        v = wp.to_torch
        self.qpos, self.qvel, self.time = v(self.d.qpos), v(self.d.qvel), v(self.d.time)
        self.ctrl, self.xfrc = v(self.d.ctrl), v(self.d.xfrc_applied)
        self.sensordata, self.M, self.qfrc_bias = v(self.d.sensordata), v(self.d.M), v(self.d.qfrc_bias)
        self.qacc_warmstart = v(self.d.qacc_warmstart)
        self.overflow = v(self.d.overflow)

    @property
    def capture(self) -> bool:
        """Whether the step phases replay captured graphs (``sim/warp_graph.py``)."""
        return self.step2.enabled

    @capture.setter
    def capture(self, enabled: bool) -> None:
        for graph in self.graphs:
            graph.enabled = bool(enabled)
        self._invalidate()

    def _invalidate(self) -> None:
        """Every phase captures again at its next call, and so does an outer capture (:attr:`generation`)."""
        for graph in self.graphs:
            graph.invalidate()
        self.generation += 1

    def launch_directly(self, stream: Any = None) -> None:
        """Inside an outer capture (``stream``: the ``wp.Stream`` object Warp's capture was registered on, or None
        on Warp's CPU device) every phase launches its kernels on that stream instead of replaying its own graph,
        until :meth:`end_direct`."""
        self.capture_stream = stream
        for graph in self.graphs:
            graph.direct = True

    def end_direct(self) -> None:
        """Back to replaying each phase's own graph (:meth:`launch_directly`)."""
        self.capture_stream = None
        for graph in self.graphs:
            graph.direct = False

    def scope(self) -> ExitStack:
        """Warp's device, and on CUDA torch's current stream, for MuJoCo Warp calls."""
        stack = ExitStack()
        stack.enter_context(wp.ScopedDevice(self.wp_device))
        if self.capture_stream is not None:  # the very object Warp registered the capture on (it looks it up by it)
            stack.enter_context(wp.ScopedStream(self.capture_stream))
        elif self.device.type == "cuda":
            stack.enter_context(wp.ScopedStream(wp.stream_from_torch(torch.cuda.current_stream(self.device))))
        return stack

    def torch_stream(self) -> Any:
        """On CUDA, the ``wp.Stream`` of torch's current stream (what the step graphs order against); else None."""
        if self.capture_stream is not None:
            return self.capture_stream
        return wp.stream_from_torch(torch.cuda.current_stream(self.device)) if self.device.type == "cuda" else None

    def batched_field(self, name: str) -> torch.Tensor:
        """A torch view (N, ...) of model field ``name``, made per-world on first use.

        Raises:
            ValueError: a field MuJoCo Warp cannot batch (naming the first allowed ones).
        """
        spec = {f.name: f.type for f in dataclasses.fields(mjw.Model)}.get(name)
        shape = getattr(spec, "shape", ())
        if not shape or shape[0] != "*":
            batchable = sorted(f.name for f in dataclasses.fields(mjw.Model)
                               if getattr(f.type, "shape", ()) and f.type.shape[0] == "*")
            raise ValueError(f"model field {name!r} cannot be set per robot on MuJoCo Warp; allowed: "
                             f"{', '.join(batchable[:12])}, ...")
        arr = getattr(self.m, name)
        if name not in self.batched:
            if arr.shape[0] != self.num_envs:
                host = arr.numpy()
                tiled = np.repeat(host[:1], self.num_envs, axis=0)
                with self.scope():
                    arr = wp.array(tiled, dtype=arr.dtype, device=self.wp_device)
                setattr(self.m, name, arr)
                self._invalidate()  # the graphs hold the replaced array's address
            self.batched.add(name)
        return wp.to_torch(arr)

    def integration_state(self) -> dict[str, torch.Tensor]:
        """Clones of the :data:`WARP_STATE_FIELDS` this model has (the non-empty ones)."""
        mj = {}
        for f in WARP_STATE_FIELDS:
            arr = getattr(self.d, f, None)
            if arr is not None and arr.size > 0:
                mj[f] = wp.to_torch(arr).clone()
        return mj

    def fields_state(self) -> dict[str, torch.Tensor]:
        """Clones of the per-world model fields, by name."""
        return {k: wp.to_torch(getattr(self.m, k)).clone() for k in sorted(self.batched)}

    def load_state(self, mj: dict[str, torch.Tensor], fields: dict[str, torch.Tensor]) -> None:
        """Write :meth:`integration_state` and :meth:`fields_state` output back (no stage is recomputed)."""
        for f, v in mj.items():
            wp.to_torch(getattr(self.d, f)).copy_(v)
        for k, v in fields.items():
            self.batched_field(k).copy_(v)

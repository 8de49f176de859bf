"""The device solve: :meth:`SamplingMPC.solve <dls_quadruped.mpc.sampler.SamplingMPC.solve>` with the ``warp`` kernel,
four Warp launches and no host synchronisation, replayed from one captured graph.

Per solve (B robots, G warm starts, M samples, N steps), after the Python-level shape checks (no tensor data is
read):

1. torch copies the inputs into this (B, G, frame) workspace's staging buffers (device-to-device, no host read);
2. the graph (``sim/warp_graph.StepGraph``: launched on the first solve, captured on the second, replayed after;
   ``wp.ScopedCapture`` on CUDA and on Warp's CPU device alike) runs
   ``clean_kernel`` (B threads: inputs cleaned, one flag per robot and input, the default frame, the solve counter
   advanced and this solve's noise seed derived from it on the device), the rollout (B x M threads,
   ``warp_kernel.rollout_kernel``), the argmin's tree levels (``warp_argmin``: 1-3 launches for M up to 10^6) and
   ``decode_kernel`` (B threads: the argmin's last stage, the winner re-drawn and decoded, the last guard);
3. torch clones the three output buffers (float32, int64, uint8) and the :class:`MPCResult` is made of views
   of the clones;
4. with ``record_step_costs``, torch rolls the winner out once more on the cleaned inputs (``decode_samples``,
   ``cost.rollout_step_costs_and_terms``: the torch path's step costs and state terms of the same winner, +inf for
   a fallback robot), eager and without a host read.

What differs from the torch path (documented in docs/mpc.md "Warp kernel"): the noise seeds come from the device
counter (not from ``SamplingMPC.generator``), a phase outside [0, 1] or a non-finite warm start sends its robot
to the fallback instead of raising, the ``reason`` is empty (:meth:`DeviceSolve.fallback_report` reads the flags
once, when asked), and ``kernel_seconds`` counts the launch (or replay) call's wall time. Arbitration between
warm-start groups takes the torch path with the ``warp`` cost kernel.
"""

from __future__ import annotations

import dataclasses
import time

import torch
import warp as wp

from dls_quadruped.mpc import warp_kernel
from dls_quadruped.mpc.cost import Refs, rollout_step_costs_and_terms
from dls_quadruped.mpc.encodings import encoded_dim
from dls_quadruped.mpc.samples import decode_samples
from dls_quadruped.mpc.solution import MPCResult, describe_bad
from dls_quadruped.mpc.solve_glue import INPUT_WIDTHS
from dls_quadruped.mpc.warp_argmin import ArgminTree
from dls_quadruped.mpc.warp_decode import (
    NUM_FLAGS,
    Outputs,
    clean_kernel,
    decode_kernel,
)
from dls_quadruped.sim.warp_graph import StepGraph

FLAG_NAMES = (*INPUT_WIDTHS, "warm_starts", "solution")
"""The per-robot flags of a device solve, in the order of ``DeviceSolve.flags``' rows."""


def _fields(b: int, n: int, dim: int) -> tuple[dict, dict, dict]:
    """(float32, int64, uint8) output fields: name -> shape per solve (field-major in each buffer)."""
    floats = {"f": (b, 4), "d": (b, 4), "foot_target_w": (b, 4, 3), "force_w": (b, 4, 3), "p_h": (b, 4, 2),
              "F_h": (b, 4, 3), "best_cost": (b,), "best_input_cost": (b,), "initial_cost": (b,),
              "best_encoded": (b, dim), "step_costs": (b, n), "step_input_costs": (b, n), "state_terms": (b, 9)}
    ints = {"best_index": (b,), "warm_start_index": (b,)}
    bools = {"contact": (b, 4), "contact_horizon": (b, n, 4), "fallback": (b,)}
    return floats, ints, bools


def _views(flat: torch.Tensor, shapes: dict) -> dict[str, torch.Tensor]:
    """{name: the field's view of ``flat``}: one split, then a view where the field is not one-dimensional."""
    parts = torch.split(flat, [torch.Size(s).numel() for s in shapes.values()])
    return {name: part if len(shape) == 1 else part.view(shape)
            for (name, shape), part in zip(shapes.items(), parts, strict=True)}


def _size(shapes: dict) -> int:
    return sum(torch.Size(s).numel() for s in shapes.values())


class DeviceSolve:
    """Buffers, constants and the captured graph of the solves of one (B, G, layout, frame) for one SamplingMPC.

    Args:
        mpc: the SamplingMPC (its config, model, device, seed).
        b, g: robots and warm starts; props: the warm starts' proportions (the sample layout).
        frame: (base_xy_w, base_yaw, terrain_z_w given) -- the defaults are computed in the clean kernel.
    """

    def __init__(self, mpc, b: int, g: int, props: tuple[float, ...], frame: tuple[bool, bool, bool]) -> None:
        with torch.inference_mode(False):  # buffers written in place by later solves, in inference mode or not
            self._build(mpc, b, g, props, frame)

    def _build(self, mpc, b: int, g: int, props: tuple[float, ...], frame: tuple[bool, bool, bool]) -> None:
        warp_kernel.init()
        cfg, dev = mpc.cfg, mpc.device
        self.cfg, self.model, self.b, self.g = cfg, mpc.model, b, g
        self.m, self.n, self.dim = cfg.num_samples, cfg.horizon, encoded_dim(cfg.encoding)
        self.device, self.wp_device = dev, warp_kernel.wp_device(dev)
        z = lambda *shape, dtype=torch.float32: torch.zeros(shape, dtype=dtype, device=dev)
        names = ("x", "phase", "base_xy", "base_yaw", "terrain_z", "h_ref", "vel_ref", "wz_ref", "foothold")
        widths = (24, 4, 2, 1, 4, 1, 2, 1, 12)
        self.staged = {k: z(b, w) for k, w in zip(names, widths, strict=True)}
        self.staged["warm"] = z(b, g, self.dim)
        self.clean = {k: torch.zeros_like(v) for k, v in self.staged.items()}
        self.flags = z(b, NUM_FLAGS, dtype=torch.uint8)
        self.seed = z(1, dtype=torch.int64)
        self.counter = mpc.solve_counter()
        self.costs = z(b, self.m)
        self.argmin = ArgminTree(b, self.m, dev)
        self.group, self.perturb = mpc.sample_layout(props)
        self.shapes = _fields(b, self.n, self.dim)
        self.out_f, self.out_i = z(_size(self.shapes[0])), z(_size(self.shapes[1]), dtype=torch.int64)
        self.out_b = z(_size(self.shapes[2]), dtype=torch.uint8)
        self.have_prev = z(b, dtype=torch.uint8)
        self.frame = frame
        self.base_seed = int(mpc.generator.initial_seed()) & 0x7FFFFFFF
        self.com_offset = wp.vec3(*mpc.model.com_offset_b)
        self.consts = [wp.from_torch(t) for t in warp_kernel.device_constants(cfg, mpc.model, str(dev))]
        self._wp = {k: wp.from_torch(v.view(-1)) for k, v in self.clean.items()}
        self._outputs = self._output_struct()
        self.graph = StepGraph(lambda _m, _d: self.launch(), None, None, self.wp_device, enabled=mpc.capture)

    def _output_struct(self) -> Outputs:
        out = Outputs()
        for buf, shapes in zip((self.out_f, self.out_i, self.out_b), self.shapes, strict=True):
            for name, view in _views(buf, shapes).items():
                setattr(out, name, wp.from_torch(view.reshape(-1)))
        out.have_prev = wp.from_torch(self.have_prev)
        return out

    def launch(self) -> None:
        """The solve's launches on the staged inputs (what the graph captures): clean, rollout, the argmin's levels,
        decode."""
        b, m, n, g, dim, dev = self.b, self.m, self.n, self.g, self.dim, self.wp_device
        s, c, a = self.staged, self._wp, lambda t: wp.from_torch(t.view(-1))
        seed = wp.from_torch(self.seed)
        wp.launch(clean_kernel, dim=b, device=dev, inputs=[
            self.base_seed, *(int(f) for f in self.frame), self.com_offset, wp.from_torch(self.counter), seed, g * dim,
            *(a(s[k]) for k in ("x", "phase", "base_xy", "base_yaw", "terrain_z", "h_ref", "vel_ref", "wz_ref",
                                "foothold", "warm")),
            *(c[k] for k in ("x", "phase", "base_xy", "base_yaw", "terrain_z", "h_ref", "vel_ref", "wz_ref",
                             "foothold", "warm")), a(self.flags)])
        kernel_inputs = [c["warm"], wp.from_torch(self.group), wp.from_torch(self.perturb),
                         *(c[k] for k in ("x", "phase", "base_xy", "base_yaw", "terrain_z", "h_ref", "vel_ref",
                                          "wz_ref", "foothold"))]
        costs = wp.from_torch(self.costs)  # (B, M): a flat array's 32-bit length would stop at B M = 2^31
        warp_kernel.launch_rollout(self.cfg, b, m, g, dev, seed, self.consts, kernel_inputs, costs)
        last = self.argmin.launch(costs, dev)
        wp.launch(decode_kernel(warp_kernel.bucket(dim)), dim=b, device=dev, inputs=[
            m, n, g, dim, seed, *self.consts, *kernel_inputs, costs, *last, a(self.flags), self._outputs])

    def stage(self, state, phase: torch.Tensor, frame: tuple, refs, warm: torch.Tensor) -> None:
        """Copy one solve's inputs into the staging buffers (a frame part not given is left): the state by one
        ``cat``, the warm starts by one copy, the rest by one ``_foreach_copy_`` where dtype and device match (one
        multi-tensor kernel on CUDA) -- three torch ops, not twelve."""
        s, b = self.staged, self.b
        parts = [state.com_pos_w, state.com_vel_w, state.euler, state.ang_vel_b, state.foot_pos_w.reshape(b, 12)]
        if all(t.dtype == torch.float32 and t.device == self.device for t in parts):
            torch.cat(parts, dim=-1, out=s["x"])
        else:
            s["x"].copy_(torch.cat([t.to(self.device, torch.float32) for t in parts], dim=-1))
        pairs = [(s["phase"], phase), (s["h_ref"].view(b), refs.com_height_w), (s["vel_ref"], refs.lin_vel_w),
                 (s["wz_ref"].view(b), refs.yaw_rate), (s["foothold"].view(b, 4, 3), refs.foothold_w)]
        for key, value in zip(("base_xy", "base_yaw", "terrain_z"), frame, strict=True):
            if value is not None:
                pairs.append((s[key].view(value.shape), value))
        same = [(d, v) for d, v in pairs if v.dtype == torch.float32 and v.device == self.device]
        if same:
            torch._foreach_copy_([d for d, _ in same], [v for _, v in same])
        for d, v in pairs:
            if v.dtype != torch.float32 or v.device != self.device:
                d.copy_(v)
        s["warm"].copy_(warm)

    def execute(self) -> None:
        """Replay (or launch) the solve on the staged inputs, ordered after torch's queued work and before torch's
        later work on CUDA: a direct launch runs on torch's current stream, a capture and its replays on the graph's
        own stream (CUDA cannot capture the legacy default stream) between two event waits (``StepGraph``)."""
        if self.device.type != "cuda":
            self.graph()
            return
        torch_stream = wp.stream_from_torch(torch.cuda.current_stream(self.device))
        with wp.ScopedStream(torch_stream, sync_enter=False, sync_exit=False):
            self.graph(torch_stream)

    def run(self) -> MPCResult:
        """:meth:`execute`, then the result: views of fresh copies of the output buffers."""
        self.execute()
        fields = {}
        for buf, shapes in zip((self.out_f, self.out_i, self.out_b), self.shapes, strict=True):
            fields.update(_views(buf.clone(), shapes))
        for name in ("contact", "contact_horizon", "fallback"):
            fields[name] = fields[name].view(torch.bool)
        return MPCResult(**fields)

    def step_costs(self, result: MPCResult) -> MPCResult:
        """``result`` with the winner's step costs and state terms (``record_step_costs``): one reference rollout of
        its decoded horizon from the cleaned inputs of this solve, as the torch path's ``decode_winners``; +inf
        for a fallback robot (its inputs were not the solve's)."""
        c, b = self.clean, self.b
        refs = Refs(c["h_ref"][:, 0], c["vel_ref"], c["wz_ref"][:, 0], c["foothold"].view(b, 4, 3))
        dec = decode_samples(result.best_encoded[:, None], c["phase"], c["base_xy"], c["base_yaw"][:, 0],
                             c["terrain_z"], self.cfg)
        steps, terms = rollout_step_costs_and_terms(c["x"], dec["contact"], dec["foot_target_w"], dec["force_w"],
                                                    refs, self.model, self.cfg.weights, self.cfg.dt)
        bad = result.fallback[:, None]
        return dataclasses.replace(result, step_costs=torch.where(bad, float("inf"), steps[:, 0]),
                                   state_terms=torch.where(bad, float("inf"), terms[:, 0]))

    def fallback_report(self) -> str:
        """The last solve's fallbacks in words ('state of robots [1] is not finite ...'): one host read."""
        flags = self.flags.to("cpu").bool()
        return describe_bad({name: flags[:, i] for i, name in enumerate(FLAG_NAMES)})


class DeviceSolver:
    """The device path of one :class:`SamplingMPC`: one :class:`DeviceSolve` per (B, G, proportions, which frame
    inputs are given), built on first use.

    Attributes:
        solves: the prepared solves, by that key.
    """

    def __init__(self) -> None:
        self.solves: dict[tuple, DeviceSolve] = {}

    def solve(self, mpc, state, refs, warm_starts, proportions, phase, base_xy_w, base_yaw,
              terrain_z_w) -> tuple[MPCResult, DeviceSolve, float]:
        """:meth:`SamplingMPC.solve`'s work on the device (module doc): no host read, one graph replay. ``mpc`` is
        read (its public configuration, layout, counter and previous result), never changed.

        Returns:
            the result, the :class:`DeviceSolve` that made it (its flags: ``fallback_report``), the wall time [s]
            of its launch or replay call.
        """
        frame = (base_xy_w, base_yaw, terrain_z_w)
        ws, props = mpc.validate_shapes(state, refs, warm_starts, proportions, phase, frame)
        b, g = state.batch_size, ws.shape[1]
        given = tuple(v is not None for v in frame)
        key = (b, g, props, given)
        work = self.solves.get(key)
        if work is None or work.cfg is not mpc.cfg or work.model is not mpc.model:
            work = self.solves[key] = DeviceSolve(mpc, b, g, props, given)
        if mpc.last_result is None:
            work.have_prev.zero_()  # no previous solution: a fallback robot gets warm start 0 decoded
        work.stage(state, phase, frame, refs, ws)
        t0 = time.perf_counter()
        result = work.run()
        seconds = time.perf_counter() - t0
        if mpc.record_step_costs:
            result = work.step_costs(result)
        return result, work, seconds

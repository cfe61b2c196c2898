"""Motion metrics: the optical flow of the generated clip against the reference's, pair by pair.

For an `Alignment` with pairs (r_0, g_0), (r_1, g_1), …, EVERY consecutive pair of pairs i, i+1
gives one reference flow ref[r_i] → ref[r_{i+1}] and one generated flow gen[g_i] → gen[g_{i+1}]
(a repeated index, as a DTW path may have, is a zero flow). The two flow fields are compared pixel
by pixel; each value below is the mean over the consecutive pairs (each pair weighs the same) of
a per-pair mean over pixels:

* ``epe``: the end-point error ‖f_ref − f_gen‖, in pixels of the ORIGINAL resolution (per frame
  interval of the pairing: one frame for the visphy pairings, three for the paper's);
* ``angle``: the space-time angular error (Barron et al. 1994; Middlebury, Baker et al. 2011) in
  degrees, the angle between the 3-vectors (u_ref, v_ref, 1) and (u_gen, v_gen, 1), with u, v in
  original pixels per frame interval of the pairing; computed as atan2(‖a × b‖, a · b), so it is
  exactly 0 for equal flows and stays defined where both flows are zero;
* ``mag_diff``: |‖f_ref‖ − ‖f_gen‖| (speed error, direction ignored), original pixels;
* the ``_moving`` variants: the same means over the *moving* pixels only, those where either
  flow's magnitude exceeds `MOVING_THRESHOLD_PX` (0.5 original pixels). A pair with no moving
  pixel in either flow (both clips still there) counts as 0 error for that pair: both clips agree
  that nothing moves.

An alignment with fewer than 2 pairs has no flow: every value is NaN (the scorer records None).

Two flow estimators, each with its six metrics (family ``motion``, kind ``sequence``, lower is
better):

* OpenCV DIS (`cv2.DISOpticalFlow`, preset ULTRAFAST with its pyramid starting at 64 px, on
  BT.601 grayscale: see `DISFlow`), weight-free, the offline default: ``flow_epe_dis``,
  ``flow_angle_dis``, ``flow_mag_diff_dis``, ``flow_epe_moving_dis``, ``flow_angle_moving_dis``,
  ``flow_mag_diff_moving_dis``;
* RAFT large (torchvision ``raft_large``; weights ``raft_large_C_T_SKHT_V2-ff5fadd5.pth``, the
  paper's ``Raft_Large_Weights.DEFAULT``, found by `visphy_core.api.weights.find`, never
  downloaded,
  and checked against the SHA-256 prefix in its name before loading: a wrong file makes the six
  metrics unavailable, ``checksum mismatch …``; torchvision's other RAFT checkpoints, such as
  ``raft_large_C_T_V2-1bb1363a.pth``, are other models and are not accepted),
  frames scaled to [−1, 1] as the weights were trained (the upstream evaluation fed [0, 1]),
  sides multiples of 8, the last of `RaftFlow.iterations` refinements: ``raft_epe``,
  ``raft_angle``, ``raft_mag_diff``, ``raft_epe_moving``, ``raft_angle_moving``,
  ``raft_mag_diff_moving``. Without the weight file they are unavailable, with the reason.

Speed: flows are computed at a reduced working resolution (`FlowEstimator.work_size`: the longer
side is brought down to 256 px, never up; 512² clips → 256²; RAFT rounds up to multiples of 8,
at least 128) and expressed in original pixels; the comparison runs on that grid (each working
pixel stands for the same area of the original).
Every flow field is memoised in the scene's `MetricInput.extra` per (estimator, clip, frame i,
frame j), and every pair's six errors per (estimator, threshold, the four frame indices), so the
six metrics of an estimator and the three pairings share them: the reference flows between
consecutive frames are the same in every pairing, and the unaligned and aligned pairings at
offset 0 share everything.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from visphy_core.api import weights
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import LOWER, SEQUENCE, Metric, MetricInput

#: A pixel is moving where either flow's magnitude exceeds this (original pixels per interval).
MOVING_THRESHOLD_PX = 0.5

#: The per-pair statistics, in the order `pair_errors` returns them.
STATISTICS = ("epe", "angle", "mag_diff", "epe_moving", "angle_moving", "mag_diff_moving")

RAFT_WEIGHT_NAMES = ("raft_large_C_T_SKHT_V2-ff5fadd5.pth",)
RAFT_URL = "https://download.pytorch.org/models/raft_large_C_T_SKHT_V2-ff5fadd5.pth"

_MEMO_KEY = "motion"


def _memo(inp: MetricInput) -> dict:
    return inp.extra.setdefault(_MEMO_KEY, {})


def _clip(inp: MetricInput, role: str) -> np.ndarray:
    return inp.reference if role == "ref" else inp.generated


# ----------------------------------------------------------------------------- estimators
class FlowEstimator:
    """A dense optical flow method at a reduced working resolution."""

    key: str = ""
    #: The longer side of the working resolution (never upscaled): flows are computed there and
    #: expressed in pixels of the original resolution.
    work_size: int = 256

    def working_shape(self, h: int, w: int) -> tuple[int, int]:
        s = min(1.0, self.work_size / max(h, w))
        return max(1, int(round(h * s))), max(1, int(round(w * s)))

    def config(self) -> str:
        """What changes its flows (part of the metrics' identity and of the memo keys)."""
        return f"{self.key}/work={self.work_size}"

    def flows(self, inp: MetricInput, todo: list[tuple[str, int, int]]) -> list[np.ndarray]:
        """The flows (2×h×w float32 planes u, v at the working shape, in original pixels) of
        the frame pairs ``todo`` ((role, i, j): clip ``ref`` or ``gen``, frame i → frame j)."""
        raise NotImplementedError

    def unavailable_reason(self) -> str | None:
        return None


class DISFlow(FlowEstimator):
    """OpenCV DIS optical flow on grayscale at the working resolution: a fixed preset whose
    pyramid starts at about `coarsest_side` px.

    Why: rendered physics scenes are small objects on flat backgrounds, and DIS's automatic
    pyramid (down to 32² at a 256² working size) smears each object's motion over every patch
    that touches it at the coarsest level: on a synthetic 512² clip of three moving disks half
    of the static background came out with more than 0.5 px of flow, so the ``_moving`` pixels
    would be mostly halo. Starting at 64² halves that halo (on the benchmark's 2D clips: from
    16 % to 6 % of the frame above 0.5 px) at the same accuracy on the objects, for less time
    (≈0.7 ms a flow on one core).

    Known limit: like any local flow, DIS cannot follow an object that moves farther than about
    its own size between the two frames (the 2D benchmark's 5 fps clips have ~20 px balls moving
    ~40 px a frame); there its flow marks where an object left and arrived, not its velocity.
    RAFT's all-pairs correlation is the estimator for those.
    """

    key = "dis"
    #: ``cv2.DISOPTICAL_FLOW_PRESET_<preset>``.
    preset = "ULTRAFAST"
    #: The longer side (working pixels) of the coarsest pyramid level: the coarsest scale is
    #: round(log2(working side / coarsest_side)) (2 for a 256² working size), the finest scale
    #: the preset's (ULTRAFAST: 2) or, if coarser, the coarsest: for 512² clips DIS then runs at
    #: one level, 64². None: OpenCV's automatic pyramid.
    coarsest_side: int | None = 64

    def config(self) -> str:
        return f"{super().config()}/preset={self.preset}/coarsest_side={self.coarsest_side}"

    def unavailable_reason(self) -> str | None:
        from visphy_plugins.metrics._torch import missing_packages

        reason = missing_packages("cv2")
        if reason is None and self.coarsest_side is not None:
            import cv2

            if not hasattr(cv2.DISOpticalFlow, "setCoarsestScale"):
                reason = (f"OpenCV {cv2.__version__} has no DISOpticalFlow.setCoarsestScale: "
                          "install a newer opencv-python-headless (scripts/setup.sh)")
        return reason

    def create(self, shape: tuple[int, int]):
        """The DIS object for frames of ``shape`` (h, w) at the working resolution."""
        import cv2

        dis = cv2.DISOpticalFlow_create(getattr(cv2, f"DISOPTICAL_FLOW_PRESET_{self.preset}"))
        if self.coarsest_side is not None:
            scale = max(0, int(round(math.log2(max(shape) / self.coarsest_side))))
            dis.setCoarsestScale(scale)
            if dis.getFinestScale() > scale:
                dis.setFinestScale(scale)
        return dis

    def _gray(self, inp: MetricInput, role: str, i: int) -> np.ndarray:
        import cv2

        memo = _memo(inp)
        key = ("gray", self.work_size, role, i)
        if key not in memo:
            frame = _clip(inp, role)[i]
            g = cv2.cvtColor(np.ascontiguousarray(frame[..., :3]), cv2.COLOR_RGB2GRAY)
            h, w = self.working_shape(*g.shape[:2])
            if (h, w) != g.shape[:2]:
                g = cv2.resize(g, (w, h), interpolation=cv2.INTER_AREA)
            memo[key] = g
        return memo[key]

    def flows(self, inp: MetricInput, todo: list[tuple[str, int, int]]) -> list[np.ndarray]:
        out = []
        dis: dict[tuple[int, int], Any] = {}
        for role, i, j in todo:
            a, b = self._gray(inp, role, i), self._gray(inp, role, j)
            if a.shape not in dis:
                dis[a.shape] = self.create(a.shape)
            flow = dis[a.shape].calc(a, b, None)
            H, W = _clip(inp, role).shape[1:3]
            out.append(_to_original_px(flow, H, W))
        return out


class RaftFlow(FlowEstimator):
    """torchvision's RAFT large, inputs in [−1, 1], sides multiples of 8, the final iteration."""

    key = "raft"
    iterations = 12          # torchvision's default number of flow updates
    batch_size = 4           # frame pairs per forward pass on the CPU
    gpu_batch_size = 16      # … on an accelerator
    min_side = 128           # torchvision's RAFT needs feature maps (1/8) of at least 16²

    def config(self) -> str:
        return f"{super().config()}/iters={self.iterations}"

    def working_shape(self, h: int, w: int) -> tuple[int, int]:
        h2, w2 = super().working_shape(h, w)
        return (max(self.min_side, math.ceil(h2 / 8) * 8),
                max(self.min_side, math.ceil(w2 / 8) * 8))

    @staticmethod
    def weight_path():
        return weights.find(*RAFT_WEIGHT_NAMES)

    def unavailable_reason(self) -> str | None:
        from visphy_plugins.metrics._torch import missing_packages

        reason = missing_packages("torch", "torchvision")
        if reason:
            return reason
        path = self.weight_path()
        if path is None:
            return weights.missing(
                "RAFT large optical flow (torchvision Raft_Large_Weights.C_T_SKHT_V2)",
                list(RAFT_WEIGHT_NAMES), extra=f"It is torchvision's download: {RAFT_URL}")
        return weights.check(path)

    def flows(self, inp: MetricInput, todo: list[tuple[str, int, int]]) -> list[np.ndarray]:
        from visphy_plugins.metrics import _torch

        t = _torch.torch()
        path = self.weight_path()
        reason = self.unavailable_reason()
        if path is None or reason:
            raise RuntimeError(reason)
        model = load_raft(path, weights.device())
        batch = self.batch_size if weights.device() == "cpu" else self.gpu_batch_size
        out: list[np.ndarray] = []
        for s in range(0, len(todo), batch):
            chunk = todo[s:s + batch]
            shapes = {_clip(inp, role).shape[1:3] for role, _, _ in chunk}
            if len(shapes) > 1:  # clips of different sizes: one pair at a time
                for one in chunk:
                    out += self.flows(inp, [one])
                continue
            H, W = shapes.pop()
            shape = self.working_shape(H, W)
            first = np.stack([_clip(inp, role)[i] for role, i, _ in chunk])
            second = np.stack([_clip(inp, role)[j] for role, _, j in chunk])
            with t.inference_mode():
                a, b = raft_input(first, shape), raft_input(second, shape)
                pred = model(a, b, num_flow_updates=self.iterations)[-1]
            flows = pred.permute(0, 2, 3, 1).float().cpu().numpy()
            out += [_to_original_px(f, H, W) for f in flows]
        return out


def raft_input(frames: np.ndarray, shape: tuple[int, int]):
    """N×H×W×3 uint8 → N×3×h×w float32 in [−1, 1] (RAFT's training range) at ``shape``
    (antialiased bilinear resize: a convex filter, so the range holds)."""
    from visphy_plugins.metrics import _torch

    t = _torch.torch()
    x = _torch.to_tensor(frames, (-1.0, 1.0))
    if tuple(x.shape[-2:]) != tuple(shape):
        x = t.nn.functional.interpolate(x, size=tuple(shape), mode="bilinear",
                                        align_corners=False, antialias=True)
    return x.clamp(-1.0, 1.0)


_RAFT_MODELS: dict[tuple, Any] = {}


def load_raft(path, device: str):
    """torchvision's ``raft_large`` with the state dict at ``path`` (checked against its
    published SHA-256 first), in eval mode on ``device``; loaded once per process (per file
    version and device)."""
    from pathlib import Path

    from visphy_plugins.metrics import _torch

    t = _torch.torch()
    p = Path(path)
    st = p.stat()
    key = (str(p.resolve()), st.st_size, st.st_mtime_ns, str(device))
    if key not in _RAFT_MODELS:
        from torchvision.models.optical_flow import raft_large

        problem = weights.check(p)  # never a file other than the published one
        if problem:
            raise RuntimeError(problem)

        state = t.load(p, map_location="cpu", weights_only=True)
        if isinstance(state, dict) and "state_dict" in state and isinstance(
                state["state_dict"], dict):
            state = state["state_dict"]
        model = raft_large(weights=None, progress=False)
        model.load_state_dict(state)
        model.eval().to(t.device(device))
        _RAFT_MODELS.clear()  # one RAFT in memory at a time
        _RAFT_MODELS[key] = model
    return _RAFT_MODELS[key]


def _to_original_px(flow: np.ndarray, H: int, W: int) -> np.ndarray:
    """A working-resolution flow (h×w×2, working pixels) as planes (2×h×w float32: u, v) in
    pixels of an H×W original."""
    h, w = flow.shape[:2]
    out = np.empty((2, h, w), np.float32)
    np.multiply(flow[..., 0], np.float32(W / w), out=out[0])
    np.multiply(flow[..., 1], np.float32(H / h), out=out[1])
    return out


# ----------------------------------------------------------------------------- comparison
def pair_errors(f_ref: np.ndarray, f_gen: np.ndarray,
                threshold: float = MOVING_THRESHOLD_PX) -> np.ndarray:
    """The six `STATISTICS` of one pair of flow fields (2×h×w float32 planes u, v on the same
    grid, original pixels). In place on temporaries only (≈1 ms at 256²)."""
    u1, v1 = f_ref
    u2, v2 = f_gen
    du, dv = u1 - u2, v1 - v2
    d2 = du * du
    d2 += dv * dv                                   # ‖f_ref − f_gen‖²
    m1 = u1 * u1
    m1 += v1 * v1
    np.sqrt(m1, out=m1)                             # ‖f_ref‖
    m2 = u2 * u2
    m2 += v2 * v2
    np.sqrt(m2, out=m2)                             # ‖f_gen‖
    # (u1, v1, 1) × (u2, v2, 1) = (dv, −du, u1·v2 − v1·u2): |cross|² = d2 + cz²
    cross = u1 * v2
    cross -= v1 * u2
    cross *= cross
    cross += d2
    np.sqrt(cross, out=cross)
    dot = u1 * u2
    dot += v1 * v2
    dot += 1.0
    ang = np.arctan2(cross, dot, out=cross)        # radians; degrees on the means
    epe = np.sqrt(d2, out=d2)
    moving = m1 > threshold
    moving |= m2 > threshold
    mag = np.subtract(m1, m2, out=m1)
    np.abs(mag, out=mag)
    maps = (epe.ravel(), ang.ravel(), mag.ravel())
    out = np.zeros(6)
    out[:3] = [float(m.sum(dtype=np.float64)) / m.size for m in maps]
    n = int(np.count_nonzero(moving))
    if n:  # else both clips still in this pair: 0 error
        weight = moving.ravel().astype(np.float32)
        out[3:] = [float(np.dot(m, weight)) / n for m in maps]
    out[[1, 4]] = np.degrees(out[[1, 4]])
    return out


def _match_grid(f_gen: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A flow (2×h×w) resampled onto another working grid (clips of different sizes; values
    already in each clip's original pixels)."""
    import cv2

    if f_gen.shape[1:] == tuple(shape):
        return f_gen
    return np.stack([cv2.resize(p, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)
                     for p in f_gen])


def sequence_errors(inp: MetricInput, alignment, estimator: FlowEstimator,
                    threshold: float = MOVING_THRESHOLD_PX) -> np.ndarray | None:
    """K×6 `STATISTICS` for the K consecutive pairs of ``alignment`` (None: fewer than 2 pairs),
    every flow and every pair's errors memoised in ``inp.extra``."""
    ri = np.asarray(alignment.ref_idx, dtype=int)
    gi = np.asarray(alignment.gen_idx, dtype=int)
    if len(ri) < 2:
        return None
    memo = _memo(inp)
    cfg = estimator.config()
    steps = list(zip(ri[:-1].tolist(), ri[1:].tolist(), gi[:-1].tolist(), gi[1:].tolist()))
    err_keys = [("errors", cfg, float(threshold), *s) for s in steps]
    todo_pairs = [s for s, k in zip(steps, err_keys) if k not in memo]
    if todo_pairs:
        wanted = {("ref", a, b) for a, b, _, _ in todo_pairs} | \
                 {("gen", c, d) for _, _, c, d in todo_pairs}
        missing = sorted(w for w in wanted
                         if w[1] != w[2] and ("flow", cfg, *w) not in memo)
        if missing:
            for w, f in zip(missing, estimator.flows(inp, missing)):
                memo[("flow", cfg, *w)] = f

        def flow(role: str, a: int, b: int) -> np.ndarray:
            if a != b:
                return memo[("flow", cfg, role, a, b)]
            H, W = _clip(inp, role).shape[1:3]
            return np.zeros((2, *estimator.working_shape(H, W)), np.float32)

        for s in todo_pairs:
            a, b, c, d = s
            fr = flow("ref", a, b)
            fg = _match_grid(flow("gen", c, d), fr.shape[1:])
            memo[("errors", cfg, float(threshold), *s)] = pair_errors(fr, fg, threshold)
    return np.stack([memo[k] for k in err_keys])


# ----------------------------------------------------------------------------- metrics
class FlowMetric(Metric):
    """One statistic of the flow comparison under one estimator (see the module docstring)."""

    family = "motion"
    kind = SEQUENCE
    direction = LOWER
    needs = ("frames",)
    version = "1"
    moving_threshold = MOVING_THRESHOLD_PX

    def __init__(self, name: str, statistic: str, estimator: FlowEstimator):
        self.name = name
        self.statistic = statistic
        self.column = STATISTICS.index(statistic)
        self.estimator = estimator
        self.score_range = (0.0, 180.0) if statistic.startswith("angle") else (0.0, math.inf)

    def unavailable_reason(self) -> str | None:
        return self.estimator.unavailable_reason()

    def identity(self) -> str:
        return (f"{super().identity()}/{self.statistic}/{self.estimator.config()}"
                f"/moving>{self.moving_threshold}")

    def compute_sequence(self, inp: MetricInput, alignment) -> float:
        errs = sequence_errors(inp, alignment, self.estimator, self.moving_threshold)
        if errs is None:
            return float("nan")
        return float(errs[:, self.column].mean())


class DISFlowMetric(FlowMetric):
    weights = None


class RaftFlowMetric(FlowMetric):
    weights = ("RAFT large (torchvision): " + " or ".join(RAFT_WEIGHT_NAMES)
               + " in metrics.weights_dir, $VISPHY_WEIGHTS or $TORCH_HOME/hub/checkpoints")

    def identity(self) -> str:
        path = RaftFlow.weight_path()
        return f"{super().identity()}/weights=" + (weights.digest(path) if path else "missing")


DIS_NAMES = {s: f"flow_{s}_dis" for s in STATISTICS}
RAFT_NAMES = {s: f"raft_{s}" for s in STATISTICS}


def motion_metrics() -> list[FlowMetric]:
    """The twelve motion metrics: six on DIS flow, six on RAFT flow."""
    dis, raft = DISFlow(), RaftFlow()
    return ([DISFlowMetric(DIS_NAMES[s], s, dis) for s in STATISTICS]
            + [RaftFlowMetric(RAFT_NAMES[s], s, raft) for s in STATISTICS])


@hookimpl
def visphy_register_metrics(register):
    for metric in motion_metrics():
        register(metric)

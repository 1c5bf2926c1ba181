"""Output files of a plan: per-robot trajectories (JSON, CSV), metrics (JSON), atomic writes.

Every writer goes through :func:`atomic_write_bytes`: the data is written to a temporary file in the target's
directory, flushed and fsync'ed, then moved over the target with ``os.replace`` (atomic on POSIX and Windows),
so a reader never sees a half-written file and a failed write leaves any previous file intact.

Outputs are deterministic: the same plan gives the same bytes (stable key order, floats written with Python's
shortest round-trip ``repr``).
"""

from __future__ import annotations

import contextlib
import csv
import io as _io
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from tmr.checks.metrics import json_safe, sample_time
from tmr.errors import ParameterError

__all__ = [
    "TRAJECTORY_FORMAT",
    "atomic_write_bytes",
    "atomic_write_text",
    "trajectories_dict",
    "write_cmd_vel",
    "write_metrics_json",
    "write_trajectories_csv",
    "write_trajectories_json",
]

#: Value of the "format" key of the trajectory JSON written by :func:`write_trajectories_json`.
TRAJECTORY_FORMAT = "tmr-trajectories/1"


# ----------------------------------------------------------------------------------------------------------
# atomic writes
# ----------------------------------------------------------------------------------------------------------
def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; return the path.

    The bytes go to a temporary file created with ``tempfile.mkstemp`` in the same directory (so
    ``os.replace`` never crosses file systems), are flushed and fsync'ed, and the temporary file is renamed
    over ``path``. On any error the temporary file is removed and the previous content of ``path`` (if any) is
    untouched. Missing parent directories are created. A new file gets mode 0644; an existing file keeps its
    mode.
    """
    path = Path(path)
    parent = path.parent
    parent.mkdir(parents=True, exist_ok=True)
    try:
        mode = path.stat().st_mode & 0o7777
    except FileNotFoundError:
        mode = 0o644
    fd, tmp = tempfile.mkstemp(dir=parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        with contextlib.suppress(OSError):  # not every file system supports chmod
            os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    if hasattr(os, "O_DIRECTORY"):  # make the rename durable (POSIX); best effort
        with contextlib.suppress(OSError):
            dfd = os.open(parent, os.O_RDONLY | os.O_DIRECTORY)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)
    return path


def atomic_write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_write_bytes`); newlines are written as
    ``\\n``."""
    return atomic_write_bytes(path, text.encode(encoding))


# ----------------------------------------------------------------------------------------------------------
# trajectories
# ----------------------------------------------------------------------------------------------------------
def _positions(robots: np.ndarray, name: str, n_samples: int, n_robots: int) -> np.ndarray:
    arr = np.asarray(robots, dtype=float)
    if arr.shape != (n_samples, n_robots, 2):
        raise ParameterError(f"{name} must have shape ({n_samples}, {n_robots}, 2) like plan.robots, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        k = int(np.flatnonzero(~np.isfinite(arr).all(axis=(1, 2)))[0])
        raise ParameterError(f"{name} has a non-finite position at sample {k}; cannot export the trajectory")
    return arr


def _robot_entries(t: list[float], robots: np.ndarray) -> list[dict[str, Any]]:
    return [
        {"name": f"robot{i + 1}", "t": t, "x": robots[:, i, 0].tolist(), "y": robots[:, i, 1].tolist()}
        for i in range(robots.shape[1])
    ]


def diff_drive_arrays(plan: Any) -> dict[str, np.ndarray] | None:
    """A differential-drive plan's per-state arrays (K+1, N): ``x``, ``y`` the axle centre [m], ``theta`` [rad],
    ``v`` [m/s], ``omega`` [rad/s], ``exit_x``, ``exit_y`` the tether's exit point [m] (``plan.robots``); None for an
    omnidirectional plan."""
    heading = getattr(plan, "heading", None)
    if heading is None:
        return None
    robots = np.asarray(plan.robots, dtype=float)
    axle = np.asarray(plan.axle, dtype=float)
    out = {
        "x": axle[..., 0],
        "y": axle[..., 1],
        "theta": np.asarray(heading, dtype=float),
        "v": np.asarray(plan.drive_v, dtype=float),
        "omega": np.asarray(plan.drive_omega, dtype=float),
        "exit_x": robots[..., 0],
        "exit_y": robots[..., 1],
    }
    for key, arr in out.items():
        if arr.shape != robots.shape[:2] or not np.all(np.isfinite(arr)):
            raise ParameterError(
                f"differential drive: {key} must be finite of shape {robots.shape[:2]}, got {arr.shape}"
            )
    return out


def _diff_entries(t: list[float], arrays: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    n = arrays["x"].shape[1]
    return [{"name": f"robot{i + 1}", "t": t, **{k: a[:, i].tolist() for k, a in arrays.items()}} for i in range(n)]


def trajectories_dict(plan: Any, filtered: np.ndarray | None = None) -> dict[str, Any]:
    """Per-robot trajectories of a plan as a JSON-ready dict (format ``"tmr-trajectories/1"``).

    Caruso 2021 §5.2: one ROS node per robot loads that robot's (t, x, y) from a JSON file and tracks it with
    a PID.
    Layout (key order as written)::

        {
          "format": "tmr-trajectories/1",
          "scenario": "A", "method": "qp", "success": true, "failure": null,
          "Ts": 0.05,                      # sample time [s]
          "n_robots": 3,
          "leader": "robot3",              # robot N = the manipulator end-effector
          "base": [x, y],                  # tether anchor [m]
          "robots": [                      # raw planner output, robot 1 (next to the base) .. robot N
            {"name": "robot1", "t": [s...], "x": [m...], "y": [m...]},
            ...
          ],
          "filtered": [ ...same as "robots"... ],  # only if `filtered` is given: zero-phase low-pass
                                                   # (tmr.checks.metrics.filter_trajectories); robots track these
          "tethers": [                     # only with an active winch: the planned horizontal tension T0 [N]
            {"name": "tether1", "t": [s...], "horizontal_tension": [N...]},
            ...
          ]
        }

    All lists of one robot have K+1 entries; ``t`` starts at the plan's first sample (0 s normally). A robot
    node reads ``doc["filtered"]`` if present, else ``doc["robots"]``, and picks its entry by ``name``.

    A differential-drive plan (``plan.heading`` set, :mod:`tmr.control.diffdrive`) adds ``"drive": "diff"`` and
    ``"robot_model"`` (its numbers) after ``"base"``, and every robot entry holds ``x``, ``y`` the axle centre [m],
    ``theta`` [rad], ``v`` [m/s], ``omega`` [rad/s] (held over [t_k, t_k+1], 0 at the end) and ``exit_x``,
    ``exit_y`` the tether's exit point [m]; it has no ``"filtered"`` (a low-passed pose would slip sideways: the
    robots execute ``cmd_vel/robotI.csv``).

    Args:
        plan: a :class:`tmr.control.clik.Plan` (fields ``t``, ``robots``, ``base``, ``scenario``, ``method``,
            ``success``, ``failure``).
        filtered: optional (K+1, N, 2) filtered positions [m].
    """
    t_arr = np.asarray(plan.t, dtype=float)
    robots = np.asarray(plan.robots, dtype=float)
    n_samples, n_robots = robots.shape[:2]
    if t_arr.shape != (n_samples,):
        raise ParameterError(f"plan.t has shape {t_arr.shape} but plan.robots has {n_samples} samples")
    robots = _positions(robots, "plan.robots", n_samples, n_robots)
    t = t_arr.tolist()
    doc: dict[str, Any] = {
        "format": TRAJECTORY_FORMAT,
        "scenario": str(plan.scenario),
        "method": str(plan.method),
        "success": bool(plan.success),
        "failure": None if plan.failure is None else str(plan.failure),
        "Ts": json_safe(sample_time(t_arr, default=math.nan)),
        "n_robots": int(n_robots),
        "leader": f"robot{n_robots}",
        "base": np.asarray(plan.base, dtype=float)[:2].tolist(),
        "robots": _robot_entries(t, robots),
    }
    diff = diff_drive_arrays(plan)
    if diff is not None:
        doc.pop("robots")
        doc["drive"] = "diff"
        doc["robot_model"] = dict((getattr(plan, "params", None) or {}).get("robot_model_params") or {})
        doc["robots"] = _diff_entries(t, diff)
        filtered = None
    if filtered is not None:
        doc["filtered"] = _robot_entries(t, _positions(filtered, "filtered", n_samples, n_robots))
    tension = getattr(plan, "winch_tension", None)
    if tension is not None:  # an active winch: every tether's planned horizontal tension
        doc["tethers"] = _tether_entries(t, tension, n_samples, n_robots)
    return doc


def _tether_entries(t: list[float], tension: Any, n_samples: int, n_robots: int) -> list[dict[str, Any]]:
    """``[{"name": "tether1", "t": [...], "horizontal_tension": [N...]}, ...]``: tether j from robot j−1 (the anchor
    for j = 1) to robot j."""
    T = np.asarray(tension, dtype=float)
    if T.shape != (n_samples, n_robots) or not np.all(np.isfinite(T)):
        raise ParameterError(f"plan.winch_tension must be finite, of shape ({n_samples}, {n_robots}); got {T.shape}")
    return [{"name": f"tether{j + 1}", "t": t, "horizontal_tension": T[:, j].tolist()} for j in range(n_robots)]


def _dumps(doc: Any, indent: int | None) -> str:
    # allow_nan=False: a NaN/inf left in the document is a bug, fail instead of writing invalid JSON
    return json.dumps(doc, indent=indent, ensure_ascii=False, allow_nan=False) + "\n"


def _dumps_readable(doc: Any, level: int = 0, indent: int = 2) -> str:
    """JSON with dicts indented one key a line and lists of scalars kept on one line (no trailing newline)."""
    pad, inner = " " * (indent * level), " " * (indent * (level + 1))
    if isinstance(doc, dict):
        if not doc:
            return "{}"
        items = [f"{inner}{_dumps(str(k), None)[:-1]}: {_dumps_readable(v, level + 1, indent)}" for k, v in doc.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(doc, list) and any(isinstance(v, (dict, list)) for v in doc):
        items = [inner + _dumps_readable(v, level + 1, indent) for v in doc]
        return "[\n" + ",\n".join(items) + "\n" + pad + "]"
    return json.dumps(doc, ensure_ascii=False, allow_nan=False)


def write_trajectories_json(plan: Any, path: str | os.PathLike[str], filtered: np.ndarray | None = None) -> Path:
    """Write :func:`trajectories_dict` to ``path`` as compact JSON (atomic, deterministic)."""
    return atomic_write_text(path, _dumps(trajectories_dict(plan, filtered), indent=None))


def write_trajectories_csv(plan: Any, path: str | os.PathLike[str], filtered: np.ndarray | None = None) -> Path:
    """Write the trajectories as CSV (atomic, deterministic).

    Columns: ``t`` [s], then ``robot1_x, robot1_y, ..., robotN_x, robotN_y`` [m] (raw), then if ``filtered``
    is given ``robot1_x_filtered, robot1_y_filtered, ...``, then with an active winch ``tether1_T0, ...`` [N] (the
    planned horizontal tension). One row per sample (K+1 rows after the header);
    floats are written with ``repr`` (shortest round-trip form); ``\\n`` line endings. A differential-drive plan:
    ``robotI_x, robotI_y`` are the axle centres, then ``robotI_theta, robotI_v, robotI_omega, robotI_exit_x,
    robotI_exit_y`` per robot [rad, m/s, rad/s, m, m]; no filtered columns.
    """
    doc = trajectories_dict(plan, filtered)  # validates shapes and finiteness
    n = doc["n_robots"]
    t = np.asarray(plan.t, dtype=float)
    blocks = [np.asarray(plan.robots, dtype=float).reshape(t.size, 2 * n)]
    header = ["t"] + [f"robot{i + 1}_{c}" for i in range(n) for c in ("x", "y")]
    diff = diff_drive_arrays(plan)
    if diff is not None:  # x, y the axle centres, then per robot theta, v, omega, exit_x, exit_y; no filtered columns
        blocks = [np.stack([diff["x"], diff["y"]], axis=-1).reshape(t.size, 2 * n)]
        keys = ("theta", "v", "omega", "exit_x", "exit_y")
        blocks.append(np.stack([diff[k] for k in keys], axis=-1).reshape(t.size, len(keys) * n))
        header += [f"robot{i + 1}_{k}" for i in range(n) for k in keys]
        filtered = None
    if filtered is not None:
        blocks.append(np.asarray(filtered, dtype=float).reshape(t.size, 2 * n))
        header += [f"robot{i + 1}_{c}_filtered" for i in range(n) for c in ("x", "y")]
    if "tethers" in doc:
        blocks.append(np.asarray(plan.winch_tension, dtype=float).reshape(t.size, n))
        header += [f"tether{j + 1}_T0" for j in range(n)]
    table = np.concatenate([t[:, None], *blocks], axis=1)
    buf = _io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    writer.writerows([[repr(v) for v in row] for row in table.tolist()])
    return atomic_write_text(path, buf.getvalue())


#: Sub-directory of a differential-drive run holding one velocity command file per robot (:func:`write_cmd_vel`).
CMD_VEL_DIR = "cmd_vel"


def write_cmd_vel(plan: Any, directory: str | os.PathLike[str]) -> list[str]:
    """Write ``robot1.csv … robotN.csv`` into ``directory`` for a differential-drive plan: columns ``t`` [s],
    ``linear_x`` = v [m/s], ``angular_z`` = ω [rad/s] (a ``geometry_msgs/Twist`` held from t until the next row; the
    last row stops the robot) and ``turn_in_place`` (1 where |v| < 1e-3 m/s and |ω| > 0.05 rad/s: the robot turns on
    the spot). Returns the names written (relative to ``directory``'s parent); nothing for an omnidirectional plan."""
    diff = diff_drive_arrays(plan)
    if diff is None:
        return []
    from tmr.checks.diffdrive import TURN_IN_PLACE

    t = np.asarray(plan.t, dtype=float)
    names = []
    for i in range(diff["v"].shape[1]):
        v, w = diff["v"][:, i], diff["omega"][:, i]
        turn = ((np.abs(v) < TURN_IN_PLACE[0]) & (np.abs(w) > TURN_IN_PLACE[1])).astype(int)
        buf = _io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(["t", "linear_x", "angular_z", "turn_in_place"])
        writer.writerows(
            [
                [repr(a), repr(b), repr(c), str(d)]
                for a, b, c, d in zip(t.tolist(), v.tolist(), w.tolist(), turn.tolist(), strict=True)
            ]
        )
        atomic_write_text(Path(directory) / f"robot{i + 1}.csv", buf.getvalue())
        names.append(f"{Path(directory).name}/robot{i + 1}.csv")
    return names


def write_metrics_json(metrics_dict: Any, path: str | os.PathLike[str]) -> Path:
    """Write a metrics dict (e.g. ``Metrics.to_dict()``, or a :class:`tmr.checks.metrics.Metrics`) as readable JSON:
    one key a line, lists of numbers on one line.

    The dict is passed through :func:`tmr.checks.metrics.json_safe` first: numpy values become plain Python values
    and non-finite floats become ``"inf"``/``"-inf"``/``"nan"`` strings. Key order is preserved (deterministic
    bytes).
    """
    if hasattr(metrics_dict, "to_dict"):
        metrics_dict = metrics_dict.to_dict()
    return atomic_write_text(path, _dumps_readable(json_safe(metrics_dict)) + "\n")

"""The structure model alone, on fixed inputs: record every call the stream makes to it (and what it read from the
map) in one run, then replay that through any checkout's model; its time a scan, and whether two checkouts give
the same bits. The stream's registration differs in its last digits from run to run (KISS-ICP's threaded sums), so
two runs of `aftershock run` can differ where one voxel sits on a threshold; a replay cannot.

    python tests/bench/structure_calls.py record REC.pkl "sim://disaster?seed=800&sensor=vlp16&scans=300"
    python tests/bench/structure_calls.py replay REC.pkl OUT.pkl [rounds]     # prints CPU ms a scan
    python tests/bench/structure_calls.py compare A.pkl B.pkl                  # IDENTICAL or what differs

Run `replay` with each checkout's own interpreter (`.venv/bin/python`) to compare two checkouts. The replay
imports torch and holds BLAS to one thread, as the stream does (numpy's temporaries cost differently without).
"""

from __future__ import annotations

import contextlib
import io
import json
import pickle
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch  # noqa: F401  (the stream's process has it loaded; see the module docstring)
from threadpoolctl import threadpool_limits

from aftershock.pipeline.structure import model as M

FIELDS = ("class_ids", "scores", "embeddings")  # what the model reads from the map besides positions
CALLS = ("explain", "update", "apply", "observe", "finish", "elements")
Event = tuple[Any, ...]


class _Shadow:
    """What the map held after the model's last call: the next call's inputs are the rows that differ."""

    def __init__(self) -> None:
        self.n = 0
        self.arrays: dict[str, np.ndarray] = {}

    def delta(self, vmap: Any) -> dict[str, Any]:
        n = len(vmap)
        d: dict[str, Any] = {"n": n, "pos": np.array(vmap.positions[self.n : n])}
        d["seq"] = np.array(vmap.first_seq[self.n : n])
        for name in FIELDS:
            cur = getattr(vmap, name)
            old = self.arrays.get(name, np.zeros((0, *cur.shape[1:]), cur.dtype))
            old = np.concatenate([old[:n], np.zeros((max(n - len(old), 0), *cur.shape[1:]), cur.dtype)])
            diff = cur != old
            rows = np.flatnonzero(diff.any(axis=1) if diff.ndim > 1 else diff)
            d[name] = (rows, np.array(cur[rows]))
        self.n = n
        return d

    def sync(self, vmap: Any) -> None:
        self.arrays = {name: np.array(getattr(vmap, name)) for name in FIELDS}


def record(out: str, source: str) -> None:
    log: list[Event] = []
    shadow, depth = _Shadow(), [0]
    orig = {name: getattr(M.StructureModel, name) for name in (*CALLS, "__init__")}

    def init(self: M.StructureModel, cfg: Any, environment: Any, voxel: float) -> None:
        log.append(("init", cfg, environment, voxel))
        orig["__init__"](self, cfg, environment, voxel)

    def wrap(name: str, args_of: Callable[..., tuple[Any, ...]]) -> Callable[..., Any]:
        def call(self: M.StructureModel, vmap: Any = None, *args: Any, **kwargs: Any) -> Any:
            if depth[0]:  # a call inside another (finish -> update): replayed by the outer one
                return orig[name](self, vmap, *args, **kwargs)
            log.append((name, None if vmap is None else shadow.delta(vmap), args_of(*args, **kwargs)))
            depth[0] += 1
            try:
                return orig[name](self, vmap, *args, **kwargs)
            finally:
                depth[0] -= 1
                if vmap is not None:
                    shadow.sync(vmap)

        return call

    M.StructureModel.__init__ = init  # type: ignore[method-assign]
    for name, args_of in (
        ("explain", lambda rows, frame: (np.array(rows), np.array(frame.pose), frame.scan.colors is not None)),
        ("update", lambda z, finishing=False: (z, finishing)),
        ("apply", lambda rewritten=None: (None if rewritten is None else np.array(rewritten),)),
        ("observe", lambda origin: (np.array(origin),)),
        ("finish", lambda: ()),
        ("elements", lambda scans=True: (scans,)),
    ):
        setattr(M.StructureModel, name, wrap(name, args_of))
    from aftershock.pipeline.cli import main

    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
        main(["run", source, "-q", "--json"])
    with open(out, "wb") as fh:
        pickle.dump(log, fh)


class _Map:
    """The map as the model saw it: positions and first scans appended, the read fields as recorded."""

    def __init__(self, embedding_dim: int) -> None:
        self.n = 0
        self.embedding_dim = embedding_dim
        self.data: dict[str, np.ndarray] = {
            "positions": np.zeros((0, 3)),
            "first_seq": np.zeros(0, np.int32),
            "class_ids": np.zeros(0, np.uint16),
            "scores": np.zeros(0, np.float32),
            "embeddings": np.zeros((0, embedding_dim), np.float32),
        }

    def __len__(self) -> int:
        return self.n

    def __getattr__(self, name: str) -> np.ndarray:
        if name in ("positions", "first_seq", *FIELDS):
            return self.__dict__["data"][name][: self.__dict__["n"]]
        raise AttributeError(name)

    def feed(self, d: dict[str, Any]) -> None:
        n = d["n"]
        for k, a in self.data.items():
            if n > len(a):
                grown = np.zeros((max(n, 2 * len(a)), *a.shape[1:]), a.dtype)
                grown[: len(a)] = a
                self.data[k] = grown
        self.data["positions"][self.n : n] = d["pos"]
        self.data["first_seq"][self.n : n] = d["seq"]
        self.n = n
        for name in FIELDS:
            rows, values = d[name]
            self.data[name][rows] = values


class _Frame:
    def __init__(self, pose: np.ndarray, colour: bool) -> None:
        self.pose = pose
        self.scan = type("Scan", (), {"colors": np.zeros(1) if colour else None})()


def replay(inp: str, out: str, rounds: int = 1) -> None:
    with open(inp, "rb") as fh:
        log: list[Event] = pickle.load(fh)
    threadpool_limits(1, user_api="blas")
    best = np.inf
    res: dict[str, Any] = {}
    for _ in range(rounds):
        model: M.StructureModel | None = None
        vmap: _Map | None = None
        spent, scans = 0.0, 0
        res = {"explain": [], "update": [], "elements": []}
        for event in log:
            if event[0] == "init":
                model = M.StructureModel(*event[1:])
                continue
            name, d, args = event
            assert model is not None
            if d is not None:
                vmap = vmap or _Map(d["embeddings"][1].shape[1])
                vmap.feed(d)
            seen: Any = vmap if d is not None else None
            t0 = time.process_time()
            if name == "explain":
                rows, pose, colour = args
                res["explain"].append(np.array(model.explain(seen, rows, _Frame(pose, colour))))  # type: ignore[arg-type]
            elif name == "update":
                res["update"].append(np.array(model.update(seen, *args)))
            elif name == "observe":
                model.observe(seen, *args)
                scans += 1
            elif name != "elements":
                getattr(model, name)(seen, *args)
            if name not in ("finish", "elements"):
                spent += time.process_time() - t0
            if name == "elements":
                res["elements"].append([e.to_json() for e in model.elements(seen, *args)])
        best = min(best, spent / max(scans, 1) * 1e3)
        assert model is not None
        res["state"] = {k: np.array(getattr(model, k)[: model.n]) for k in ("elem", "kind_cls", "fused", "fused_score")}
        res["map"] = {} if vmap is None else {k: np.array(getattr(vmap, k)) for k in ("class_ids", "scores")}
        print(f"{spent / max(scans, 1) * 1e3:.2f} ms a scan over {scans} scans (explain, observe, update, apply)")
    res["ms"] = best
    with open(out, "wb") as fh:
        pickle.dump(res, fh)


def compare(a_path: str, b_path: str) -> bool:
    with open(a_path, "rb") as fa, open(b_path, "rb") as fb:
        a, b = pickle.load(fa), pickle.load(fb)
    same = True
    for key in ("explain", "update"):
        if len(a[key]) != len(b[key]) or not all(np.array_equal(x, y) for x, y in zip(a[key], b[key], strict=True)):
            print(f"differs: the rows {key} returned")
            same = False
    for group in ("state", "map"):
        for k in a[group]:
            if not np.array_equal(a[group][k], b[group][k]):
                print(f"differs: {group} {k}")
                same = False
    if json.dumps(a["elements"]) != json.dumps(b["elements"]):
        print("differs: elements")
        same = False
    print(("IDENTICAL" if same else "DIFFERENT") + f"; ms a scan {a['ms']:.2f} -> {b['ms']:.2f}")
    return same


if __name__ == "__main__":
    cmd, *rest = sys.argv[1:]
    if cmd == "record":
        record(rest[0], rest[1])
    elif cmd == "replay":
        replay(rest[0], rest[1], int(rest[2]) if len(rest) > 2 else 1)
    else:
        sys.exit(0 if compare(rest[0], rest[1]) else 1)

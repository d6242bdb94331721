"""Two gloo processes: own envs and seeds, averaged gradients, identical parameters."""

from __future__ import annotations

import os
import socket

import torch
import torch.multiprocessing as mp

from training_fixtures import tiny_config


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _worker(rank: int, world: int, port: int, out: str) -> None:
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank),
                      WORLD_SIZE=str(world), LOCAL_RANK=str(rank))
    torch.set_num_threads(1)
    from collavn.training import distributed
    from collavn.training.trainer import build_run, collect_rollout, learn, sync_point

    info, device = distributed.setup("cpu")
    try:
        cfg = tiny_config("no-mem", rollout_steps=3)
        run = build_run(cfg, info, device)
        before = {k: v.clone() for k, v in run.model.state_dict().items()}
        sync_point(run)
        rollout, _ = collect_rollout(run)
        learn(run, rollout)
        torch.save({"before": before, "after": run.model.state_dict(),
                    "panorama": rollout.obs["panorama"], "seed": info.seed(cfg.run.seed)},
                   os.path.join(out, f"rank{rank}.pt"))
    finally:
        distributed.cleanup()


def test_two_gloo_processes_keep_identical_parameters(tmp_path):
    mp.spawn(_worker, args=(2, _free_port(), str(tmp_path)), nprocs=2, join=True)
    r0 = torch.load(tmp_path / "rank0.pt", weights_only=False)
    r1 = torch.load(tmp_path / "rank1.pt", weights_only=False)
    assert (r0["seed"], r1["seed"]) == (0, 1000)
    assert not torch.equal(r0["panorama"], r1["panorama"])  # each rank has its own episodes
    for k in r0["after"]:
        assert torch.equal(r0["before"][k], r1["before"][k]), k
        assert torch.equal(r0["after"][k], r1["after"][k]), k
    changed = [k for k in r0["after"] if not torch.equal(r0["before"][k], r0["after"][k])]
    assert changed, "the update did not change any parameter"

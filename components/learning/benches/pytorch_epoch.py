"""PyTorch's seconds per training epoch at the shapes `bowden bench train` times.

The same networks as bowden's (the paper's LSTM(5, 128) -> 64 -> ReLU -> 5 and the TCN of 5
residual blocks, k = 3, dilations 1..16, channels = joints, second conv linear), the same
epoch (24,565 windows of L = 80, J = 5, batch 32, shuffled, Adam lr 1e-3, MSE on the last
step's output), on the same number of threads, so the two can be timed in one run on one
machine:

    python3 -m venv /tmp/torchenv && /tmp/torchenv/bin/pip install torch
    /tmp/torchenv/bin/python components/learning/benches/pytorch_epoch.py --arch lstm --threads 2
    cargo run --release -- bench train --arch lstm

or let bowden run it beside its own epoch: `bowden bench train --pytorch /tmp/torchenv/bin/python`.

Data are random (an epoch's cost does not depend on the values). Prints one line per epoch
and the median, and a JSON line at the end.
"""

import argparse
import json
import statistics
import time

import torch
from torch import nn


class Lstm(nn.Module):
    def __init__(self, joints, hidden=128, head=64):
        super().__init__()
        self.lstm = nn.LSTM(joints, hidden, batch_first=True)
        self.fc = nn.Sequential(nn.Linear(hidden, head), nn.ReLU(), nn.Linear(head, joints))

    def forward(self, x):
        y, _ = self.lstm(x)
        return self.fc(y[:, -1, :])


class CausalConv(nn.Module):
    def __init__(self, ch, dilation, k=3):
        super().__init__()
        self.pad = (k - 1) * dilation
        self.conv = nn.Conv1d(ch, ch, k, dilation=dilation)

    def forward(self, x):
        return self.conv(nn.functional.pad(x, (self.pad, 0)))


class Block(nn.Module):
    def __init__(self, ch, dilation):
        super().__init__()
        self.c1 = CausalConv(ch, dilation)
        self.c2 = CausalConv(ch, dilation)

    def forward(self, x):
        return x + self.c2(torch.relu(self.c1(x)))


class Tcn(nn.Module):
    def __init__(self, joints, blocks=5):
        super().__init__()
        self.blocks = nn.Sequential(*[Block(joints, 2**i) for i in range(blocks)])

    def forward(self, x):
        return self.blocks(x.transpose(1, 2))[:, :, -1]


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--arch", choices=["lstm", "tcn"], default="lstm")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--windows", type=int, default=24_565)
    p.add_argument("--seq-len", type=int, default=80)
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--epochs", type=int, default=3)
    p.add_argument("--bf16", action="store_true",
                   help="mixed precision: autocast the forward to bfloat16 (CPU AMP)")
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    joints = 5
    x = torch.randn(a.windows, a.seq_len, joints)
    y = torch.randn(a.windows, joints)
    model = Lstm(joints) if a.arch == "lstm" else Tcn(joints)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    loss_fn = nn.MSELoss()

    def epoch(limit=None):
        order = torch.randperm(a.windows)
        n = 0
        for start in range(0, a.windows, a.batch):
            idx = order[start : start + a.batch]
            opt.zero_grad(set_to_none=True)
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=a.bf16):
                out = model(x[idx])
            loss = loss_fn(out.float(), y[idx])
            loss.backward()
            opt.step()
            n += 1
            if limit is not None and n >= limit:
                return

    epoch(limit=8)  # warm-up, as bowden's timer does
    secs = []
    for e in range(a.epochs):
        t0 = time.perf_counter()
        epoch()
        secs.append(time.perf_counter() - t0)
        print(f"{a.arch} epoch {e}: {secs[-1]:.3f} s", flush=True)
    med = statistics.median(secs)
    prec = "bf16" if a.bf16 else "f32"
    print(f"{a.arch} {prec} median {med:.3f} s/epoch, torch {torch.__version__}, {a.threads} thread(s)")
    print(json.dumps({"arch": a.arch, "precision": prec, "torch": torch.__version__, "threads": a.threads,
                      "epoch_seconds": secs, "median_seconds": med}))


if __name__ == "__main__":
    main()

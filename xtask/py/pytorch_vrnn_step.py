"""PyTorch eager reference for `cargo xtask bench-train`: seconds per training
step (forward, backward, Adam) of the paper's VRNN at T = 128, on the CPU.

The model is the paper's (docs/training.md): feature extractor 58 -> 48 -> 32
(ReLU), prior and encoder heads (mean, sigmoid std) on h and [x'', h], decoder
[z, h] -> 32 -> 48 -> 58, LSTM cell on [x'', z] with hidden 32, latent 8; loss
= squared error + KL per step, summed over time, averaged over the batch. The
feature extractor runs once over all frames; the rest steps through time, as an
eager implementation does. With --hoisted, only what the recurrence needs (the
encoder and the LSTM cell) steps through time, and the prior, the decoder and
both losses run once over all frames after the loop (the fastest eager form).

    python3 xtask/py/pytorch_vrnn_step.py [--batch 1600 64] [--steps 10] [--threads 2] [--hoisted]
"""

import argparse
import statistics
import time

import torch
from torch import nn

F, E1, E2, H, Z, D1, D2, T = 58, 48, 32, 32, 8, 32, 48, 128


class Vrnn(nn.Module):
    def __init__(self):
        super().__init__()
        self.phi_x = nn.Sequential(nn.Linear(F, E1), nn.ReLU(), nn.Linear(E1, E2), nn.ReLU())
        self.prior_mean, self.prior_std = nn.Linear(H, Z), nn.Linear(H, Z)
        self.enc_mean, self.enc_std = nn.Linear(E2 + H, Z), nn.Linear(E2 + H, Z)
        self.decoder = nn.Sequential(
            nn.Linear(Z + H, D1), nn.ReLU(), nn.Linear(D1, D2), nn.ReLU(), nn.Linear(D2, F)
        )
        self.rnn = nn.LSTMCell(E2 + Z, H)

    def forward(self, x, eps):
        b = x.shape[0]
        feat = self.phi_x(x)
        h = x.new_zeros(b, H)
        c = x.new_zeros(b, H)
        recon = x.new_zeros(())
        kl = x.new_zeros(())
        for t in range(x.shape[1]):
            f = feat[:, t]
            eh = torch.cat([f, h], 1)
            mq = self.enc_mean(eh)
            sq = torch.sigmoid(self.enc_std(eh)).clamp(min=1e-4)
            if t == 0:
                mp, sp = torch.zeros_like(mq), torch.ones_like(sq)
            else:
                mp = self.prior_mean(h)
                sp = torch.sigmoid(self.prior_std(h)).clamp(min=1e-4)
            z = mq + sq * eps[t]
            xh = self.decoder(torch.cat([z, h], 1))
            recon = recon + ((xh - x[:, t]) ** 2).sum()
            kl = kl + (torch.log(sp / sq) + (sq**2 + (mq - mp) ** 2) / (2 * sp**2) - 0.5).sum()
            h, c = self.rnn(torch.cat([f, z], 1), (h, c))
        return recon / b, kl / b

    def forward_hoisted(self, x, eps):
        b = x.shape[0]
        feat = self.phi_x(x)
        h = x.new_zeros(b, H)
        c = x.new_zeros(b, H)
        hs, zs, mqs, sqs = [], [], [], []
        for t in range(x.shape[1]):
            f = feat[:, t]
            eh = torch.cat([f, h], 1)
            mq = self.enc_mean(eh)
            sq = torch.sigmoid(self.enc_std(eh)).clamp(min=1e-4)
            z = mq + sq * eps[t]
            hs.append(h)
            zs.append(z)
            mqs.append(mq)
            sqs.append(sq)
            h, c = self.rnn(torch.cat([f, z], 1), (h, c))
        h, z = torch.stack(hs, 1), torch.stack(zs, 1)
        mq, sq = torch.stack(mqs, 1), torch.stack(sqs, 1)
        mp = self.prior_mean(h)
        sp = torch.sigmoid(self.prior_std(h)).clamp(min=1e-4)
        first = torch.zeros(1, x.shape[1], 1, dtype=torch.bool)
        first[:, 0] = True
        mp = torch.where(first, torch.zeros_like(mp), mp)
        sp = torch.where(first, torch.ones_like(sp), sp)
        xh = self.decoder(torch.cat([z, h], 2))
        recon = ((xh - x) ** 2).sum()
        kl = (torch.log(sp / sq) + (sq**2 + (mq - mp) ** 2) / (2 * sp**2) - 0.5).sum()
        return recon / b, kl / b


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, nargs="+", default=[1600, 64])
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--hoisted", action="store_true")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    model = Vrnn()
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    run = model.forward_hoisted if a.hoisted else model.forward
    form = "hoisted" if a.hoisted else "stepwise"
    print(f"PyTorch {torch.__version__} eager ({form}), {a.threads} threads, T = {T}")
    print("batch   median s      min s")
    for b in a.batch:
        x = torch.randn(b, T, F)
        times = []
        for k in range(a.steps + 2):
            eps = torch.randn(T, b, Z)
            start = time.perf_counter()
            opt.zero_grad()
            recon, kl = run(x, eps)
            (recon + kl).backward()
            opt.step()
            if k >= 2:
                times.append(time.perf_counter() - start)
        print(f"{b:>5} {statistics.median(times):>10.4f} {min(times):>10.4f}")


if __name__ == "__main__":
    main()

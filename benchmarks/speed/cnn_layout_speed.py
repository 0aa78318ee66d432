"""Milliseconds of the image coder (Fig. 14's CNN) by memory layout and chunking, in one process, variants in turn.

    python -m benchmarks.speed.cnn_layout_speed [--frames 1792] [--grad-frames 512] [--rounds 5] [--name cnn_layout_speed]

Variants: ``nchw`` (contiguous weights and input, the whole batch at once), ``input_channels_last`` (the input
channels-last, the weights contiguous: the package before its image coder held channels-last weights),
``channels_last`` (weights and input channels-last, what :class:`~torchrl_mpail2.modules.encoder.ImageCoder` does),
and each in chunks of 64 frames.
Two workloads: a stop-gradient encode of ``--frames`` uint8 frames (the dynamics loss's targets at batch 256, two
cameras, H = 7) and a forward and backward pass of ``--grad-frames`` (the encoded first frames). One torch thread,
glibc told to keep freed memory (``retain_freed_memory``, as the trainer does). Medians over rounds; writes
``docs/results/speed/<name>.json`` and ``.md``.
"""
from __future__ import annotations

import argparse
import statistics
import time

from benchmarks.records import ROOT, write_record

RESULTS = ROOT / "docs" / "results" / "speed"
CHUNK = 64


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", type=int, default=1792)
    p.add_argument("--grad-frames", type=int, default=512)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--name", default="cnn_layout_speed")
    p.add_argument("--note", default="", help="what else ran on the machine")
    args = p.parse_args()

    import torch
    import torch.nn.functional as F

    from torchrl_mpail2.agents.update import retain_freed_memory
    from torchrl_mpail2.modules.encoder import ImageCoder

    torch.set_num_threads(1)
    retain_freed_memory()
    torch.manual_seed(0)
    coder = ImageCoder((3, 64, 64), 32, 256)
    convs = [m for m in coder.convs if isinstance(m, torch.nn.Conv2d)]
    # (input layout, weight layout) of each variant
    layouts = {"nchw": (torch.contiguous_format,) * 2, "input_channels_last": (torch.channels_last, torch.contiguous_format),
               "channels_last": (torch.channels_last,) * 2}
    weights = {name: [(c.weight.detach().clone().contiguous(memory_format=fmt[1]).requires_grad_(), c.bias)
                      for c in convs] for name, fmt in layouts.items()}

    def encode(x, layout):
        h = x.contiguous(memory_format=layouts[layout][0]).float() / 255.0 - 0.5
        for (w, b), conv in zip(weights[layout], convs):
            h = F.silu(F.conv2d(h, w, b, stride=conv.stride))
        return coder.out(h.flatten(1))

    def run(x, layout, chunked):
        return torch.cat([encode(part, layout) for part in x.split(CHUNK)]) if chunked else encode(x, layout)

    frames = torch.randint(0, 256, (args.frames, 3, 64, 64), dtype=torch.uint8)
    grad_frames = frames[: args.grad_frames].clone()
    variants = [(layout, chunked) for layout in layouts for chunked in (False, True)]
    times = {(v, w): [] for v in variants for w in ("stop_gradient", "forward_backward")}
    for round_ in range(args.rounds + 1):  # the first round warms up
        for layout, chunked in variants:
            start = time.perf_counter()
            with torch.no_grad():
                run(frames, layout, chunked)
            middle = time.perf_counter()
            run(grad_frames, layout, chunked).square().sum().backward()
            end = time.perf_counter()
            if round_:
                times[(layout, chunked), "stop_gradient"].append((middle - start) * 1e3)
                times[(layout, chunked), "forward_backward"].append((end - middle) * 1e3)
    rows = [{"layout": layout, "chunked": chunked, "workload": workload, "ms": statistics.median(ms), "ms_all": ms}
            for ((layout, chunked), workload), ms in times.items()]
    base = {r["workload"]: r["ms"] for r in rows if r["layout"] == "nchw" and not r["chunked"]}
    for r in rows:
        r["speedup_vs_nchw"] = base[r["workload"]] / r["ms"]

    def markdown(commit) -> str:
        lines = [f"# Image coder: memory layout and chunks (commit {commit})", "",
                 f"One thread, {args.rounds} rounds, variants in turn; stop-gradient encode of {args.frames} frames, "
                 f"forward + backward of {args.grad_frames}. {args.note}", "",
                 "| layout | chunks of 64 | workload | ms | x nchw |", "|---|---|---|---:|---:|"]
        lines += [f"| {r['layout']} | {'yes' if r['chunked'] else 'no'} | {r['workload']} | {r['ms']:.0f} | "
                  f"{r['speedup_vs_nchw']:.2f} |" for r in sorted(rows, key=lambda r: (r['workload'], r['layout']))]
        return "\n".join(lines) + "\n"

    write_record(RESULTS, args.name, {"frames": args.frames, "grad_frames": args.grad_frames, "rounds": args.rounds,
                                      "rows": rows}, args.note, ROOT, markdown)
    print(markdown(None))


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Dump a TensorBoard log folder (e.g. an rtf run's RUN/tb/) as JSON, read with TensorBoard's
own event reader: {"scalars": {tag: [[step, value], ...]},
                   "images": {tag: [[step, width, height, png_bytes], ...]}}.

Used by rtf's tests to check the event files against log.jsonl; handy to diff runs too:
    .venv/bin/python scripts/tb_read.py runs/mfnet/tb > tb.json
"""
import json
import sys

from tensorboard.backend.event_processing import event_accumulator as ea


def main() -> None:
    if len(sys.argv) != 2:
        sys.exit("usage: tb_read.py TB_DIR")
    acc = ea.EventAccumulator(sys.argv[1], size_guidance={ea.SCALARS: 0, ea.IMAGES: 0})
    acc.Reload()
    tags = acc.Tags()
    out = {
        "scalars": {t: [[e.step, e.value] for e in acc.Scalars(t)] for t in tags["scalars"]},
        "images": {
            t: [[e.step, e.width, e.height, len(e.encoded_image_string)] for e in acc.Images(t)]
            for t in tags["images"]
        },
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()

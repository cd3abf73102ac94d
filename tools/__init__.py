"""Command-line tools of radar-fusion: simulate, replay, record, evaluate, bench, demo."""

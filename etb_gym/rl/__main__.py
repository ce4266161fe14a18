"""``python -m etb_gym.rl compare OUT/results.csv --agent rl:DIR``: the RMS comparison table."""
from .evaluate import compare_main

raise SystemExit(compare_main())

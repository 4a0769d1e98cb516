"""The trusted fill's bench (python -m pipeline.bench.trust_bench) runs end to end on a few windows."""

import numpy as np


def test_trust_bench_fills_every_method_and_decides_every_window():
    from pipeline.bench.trust_bench import METHODS, run_trust_bench

    r = run_trust_bench(("eval",), limit=25, transitions=(5,))["sources"]["eval"]
    res = r["results"][5]
    assert r["windows"] > 0
    for m in METHODS:
        assert np.isfinite(res[m]["L2P"]) and res[m]["L2P"] > 0
    assert sum(res["choices"].values()) == r["windows"]
    # The decided fill lies between its two candidates (a blend, window by window).
    lo, hi = sorted((res["model"]["L2P"], res["spline"]["L2P"]))
    assert lo * 0.9 <= res["decided"]["L2P"] <= hi * 1.1

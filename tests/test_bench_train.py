"""``ftgspp bench train`` runs every CPU backend through the real trainer and reports ratios."""

import json

from ftgspp.bench import main


def test_bench_train_json(capsys):
    assert main(["train", "--iterations", "4", "--budget", "200", "--repeats", "1",
                 "--width", "64", "--height", "48", "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(out["backends"]) == {"reference", "cpu"}
    for r in out["backends"].values():
        assert r["ms_per_iter"] > 0 and len(r["all_ms"]) == 1
    assert out["speedup_vs_reference"]["reference"] == 1.0

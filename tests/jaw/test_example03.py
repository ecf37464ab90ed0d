"""examples/03_jaw_rigs.py at small size (fewer mandible points, a shorter NLPCA training)."""

import importlib.util
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "03_jaw_rigs.py"


def test_03_jaw_rigs(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("example_03_jaw_rigs", EXAMPLE)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    results = example.main(["--out", str(tmp_path), "--points", "150", "--nlpca-iterations", "200"])
    printed = capsys.readouterr().out
    for name in ("rigs.png", "envelope.png", "retarget.png"):
        png = tmp_path / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 30_000, name
    # Zoss Fig. 8 on motion generated for the shipped TMJ
    mean = {name: e.mean for name, e in results["rigs"].items()}
    assert mean["1dof"] > mean["3dof"] > mean["5dof"] > mean["posselt"], mean
    assert mean["posselt"] < 0.2 and results["rigs"]["posselt"].p95 < 1.0 and mean["nlpca"] < 0.3
    # NLPCA beats linear PCA with 3 parameters
    nl = results["reconstruction"]
    assert nl.nlpca[3][0] < nl.pca[3][0] and nl.nlpca[3][1] < nl.pca[3][1]
    # the envelope found without labels is the labelled one
    assert results["envelope_gap"].mean() < 0.2 and results["envelope_gap"].max() < 1.0
    # retargeting: full < reduced < unadapted, a rig fitted on the subject's own session best
    e = {mode: r.mean for mode, r in results["retarget"].items()}
    assert e["fitted"] < e["full"] < e["reduced"] < e["none"], e
    # the printed tables carry the same numbers
    assert f"{results['rigs']['posselt'].mean:.3f}" in printed and f"{e['full']:.3f}" in printed
    assert "Yang et al. 2018: 1.73 mm mean" in printed

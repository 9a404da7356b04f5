"""Numbers the README states about the test suite itself match the suite (they went stale before:
issue 23 found 58 bad-input rows documented where there were 88; that count is checked beside its
table, in tests/test_cli_bad_inputs.py)."""
from conftest import REPO


def test_readme_exactness_claim_is_the_tested_range():
    """README: exact fringe orders "for every method up to 384 periods": MF, MW and NT are each
    tested at 384 (tests/test_unwrap_temporal.py)."""
    import test_unwrap_temporal as t

    assert "for every method up to 384 periods" in (REPO / "README.md").read_text()
    assert max(max(ladder) for ladder in t.MF_LADDERS) >= 384
    marks = {m.args[0]: m.args[1] for f in (t.test_mw_exact_on_noise_free_stacks, t.test_nt_exact_on_noise_free_stacks)
             for m in f.pytestmark if m.name == "parametrize"}
    assert max(max(f) for f in marks["freqs"]) >= 384 and max(max(p) for p in marks["pair"]) >= 384

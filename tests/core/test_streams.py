"""Named random streams: the dataset's two streams keep their original derivation bit for bit, every
other stream is independent of them and of each other, and unknown names are refused."""

import numpy as np
import pytest

from forcdecode.core.streams import STREAMS, seed_sequence, stream_rng, stream_seed

REQUIRED = ("parameters", "disorder", "split", "alice", "alice_fold", "bob", "mc_dropout", "learning_curve",
            "cross_fitting", "ensemble", "bootstrap", "closed_loop_subset", "closed_loop_disorder", "figure_samples",
            "baseline_shuffle")


def test_every_required_stream_is_declared_with_a_description():
    assert set(REQUIRED) <= set(STREAMS)
    assert all(isinstance(text, str) and len(text) > 10 for text in STREAMS.values())


@pytest.mark.parametrize("name, legacy_id", [("parameters", 0), ("disorder", 1)])
def test_dataset_streams_are_the_original_seed_sequences(name, legacy_id):
    """dataset/params.py drew from SeedSequence([seed, sample_id, stream]) with stream 0 / 1."""
    for seed, sample_id in ((0, 0), (7, 3), (20261122, 57), (20261122, 79_999)):
        original = np.random.default_rng(np.random.SeedSequence([seed, sample_id, legacy_id]))
        assert np.array_equal(stream_rng(seed, name, sample_id).random(8), original.random(8))


def test_pinned_values():
    """Literal draws: a change of the derivation (or of NumPy's PCG64 stream) fails here."""
    assert stream_rng(7, "parameters", 3).random(3).tolist() == [0.9750335537195014, 0.8845672371187709,
                                                                 0.23197043322658195]
    assert stream_rng(20261122, "disorder", 0).integers(0, 2**31, 3).tolist() == [1279886307, 73631627, 1638604674]
    assert stream_rng(7, "split").random(2).tolist() == [0.6320442355695731, 0.48677827296439047]
    assert stream_seed(7, "alice", "K_u") == 477890606546862685


def test_streams_are_independent_and_reproducible():
    draws = {}
    for name in STREAMS:
        keys = (3,) if name in ("parameters", "disorder") else (3, "K_u")
        draws[name] = stream_rng(11, name, *keys).random(4)
        assert np.array_equal(draws[name], stream_rng(11, name, *keys).random(4))
    values = np.array(list(draws.values()))
    assert len({tuple(row) for row in values}) == len(STREAMS)
    # different keys and different seeds give different draws; key order matters
    assert stream_rng(11, "alice_fold", "D", 0).random() != stream_rng(11, "alice_fold", "D", 1).random()
    assert stream_rng(11, "alice_fold", 1, 2).random() != stream_rng(11, "alice_fold", 2, 1).random()
    assert stream_rng(11, "split").random() != stream_rng(12, "split").random()


def test_trailing_zero_keys_do_not_alias():
    """SeedSequence pads short entropy with zeros; keys sit in the spawn key, so (k,) ≠ (k, 0)."""
    assert stream_rng(5, "ensemble", 2).random() != stream_rng(5, "ensemble", 2, 0).random()
    assert stream_rng(5, "ensemble").random() != stream_rng(5, "ensemble", 0).random()
    # no new stream coincides with a dataset stream of the same seed and sample
    assert stream_rng(5, "split", 0).random() != stream_rng(5, "parameters", 0).random()


def test_stream_seed_is_a_63_bit_integer_for_torch():
    seeds = [stream_seed(s, "bob", name) for s in range(20) for name in ("N_pin", "D")]
    assert all(isinstance(s, int) and 0 <= s < 2**63 for s in seeds)
    assert len(set(seeds)) == len(seeds)
    assert stream_seed(3, "bob", "D") == stream_seed(3, "bob", "D")


def test_refusals():
    with pytest.raises(ValueError, match="unknown random stream 'nope'"):
        stream_rng(1, "nope")
    with pytest.raises(ValueError, match="exactly one key"):
        stream_rng(1, "disorder")
    with pytest.raises(ValueError, match="non-negative"):
        seed_sequence(1, "split", -1)
    with pytest.raises(TypeError):
        seed_sequence(1, "split", 1.5)
    with pytest.raises(TypeError):
        seed_sequence("7", "split")

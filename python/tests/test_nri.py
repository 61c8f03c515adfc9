"""Our NRI against NRI: the batched decoder computes what NRI's per-type,
per-pair loop computes (outputs, loss and gradients), the springs simulation
is NRI's, and on a small springs set our NRI finds the springs well above
chance. The long runs (the paper's figure, epoch times) are benchmarks:
``make bench-methods``."""

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason='the reference methods need pip install "./python[methods]"')

from causalcity.methods import make, springs  # noqa: E402
from causalcity.methods.common import auroc_of  # noqa: E402
from causalcity import InputError  # noqa: E402
from causalcity.methods.nri import MlpDecoder, RnnDecoder, TrailDecoder  # noqa: E402


CARS = 5
PAIRS = [(i, j) for i in range(CARS) for j in range(CARS) if i != j]
SEND, RECV = torch.tensor([p[0] for p in PAIRS]), torch.tensor([p[1] for p in PAIRS])


def assert_batched_is_the_loop(decoder, seq, past, edges):
    """The batched step and NRI's per-type, per-pair loop give the same
    outputs, loss and gradients (float64), the edge weights' gradient (what
    trains the encoder) included."""
    losses, grads = [], []
    for reference in (False, True):
        decoder.zero_grad()
        weights = edges.detach().clone().requires_grad_(True)
        out = decoder(seq, past, weights, truth_until=4, reference=reference)
        loss = ((out - seq[:, 1:]) ** 2).sum()
        loss.backward()
        losses.append(loss.item())
        grads.append(torch.cat([p.grad.flatten() for p in decoder.parameters() if p.grad is not None]
                               + [weights.grad.flatten()]))  # fmt: skip
    assert losses[0] == pytest.approx(losses[1], rel=1e-12)
    assert torch.allclose(grads[0], grads[1], rtol=1e-9, atol=1e-12)
    assert grads[0].abs().sum() > 0 and grads[0][-edges.numel() :].abs().sum() > 0


def inputs(types: int, seed: int):
    torch.manual_seed(seed)
    seq = torch.randn(3, 12, CARS, 4, dtype=torch.float64)
    edges = torch.softmax(torch.randn(3, len(PAIRS), types, dtype=torch.float64), -1)
    return seq, edges


@pytest.mark.parametrize("types, skip_first", [(2, True), (1, False), (3, False)])
def test_the_batched_decoder_is_nri_s_loop(types, skip_first):
    seq, edges = inputs(types, types)
    decoder = RnnDecoder(4, 16, types, skip_first, SEND, RECV, window=6).double()
    decoder.vel_to_pos = torch.tensor([0.7, 1.3], dtype=torch.float64)
    decoder.vel_offset = torch.tensor([0.01, -0.02], dtype=torch.float64)
    past = torch.randn(3, CARS, 6, 4, dtype=torch.float64)
    assert_batched_is_the_loop(decoder, seq, past, edges)


@pytest.mark.parametrize("types, skip_first", [(2, True), (1, False), (3, False)])
def test_the_trail_decoder_on_the_grid_is_the_pair_by_pair_loop(types, skip_first):
    seq, edges = inputs(types, 20 + types)
    decoder = TrailDecoder(4, 16, types, skip_first, SEND, RECV, window=6).double()
    decoder.vel_to_pos = torch.tensor([0.7, 1.3], dtype=torch.float64)
    decoder.vel_offset = torch.tensor([0.01, -0.02], dtype=torch.float64)
    past = torch.randn(3, CARS, 6, 4, dtype=torch.float64)
    assert_batched_is_the_loop(decoder, seq, past, edges)


def test_a_trail_message_reaches_only_a_car_on_its_sender_s_trail():
    # Car 0 drove along y = 0 and turned; car 1 stands on that road where car
    # 0 was 3 frames ago, car 2 far off it. Car 0's message to car 1 says
    # where car 0 went from there; car 2 hears (almost) nothing.
    decoder = TrailDecoder(4, 8, 2, True, SEND[:0], RECV[:0], window=6).double()
    decoder.vel_to_pos = torch.tensor([1.0, 1.0], dtype=torch.float64) / 2**0.5  # distances in these units
    with torch.no_grad():
        decoder.log_temperature.fill_(-3.0)  # as training sharpens it
    trail = torch.zeros(6, 4, dtype=torch.float64)
    trail[:, 0] = -torch.arange(6, dtype=torch.float64)  # x: 0, -1, ... -5 (newest first)
    trail[:, 2] = 1.0
    trail[2, 2:] = torch.tensor([0.0, 1.0], dtype=torch.float64)  # from x = -3 it went up
    here = torch.tensor([[-3.0, 0.0], [-3.0, 40.0]], dtype=torch.float64)
    velocity = torch.tensor([[1.0, 0.0], [1.0, 0.0]], dtype=torch.float64)
    features, gate = decoder._trail(here, velocity, trail.expand(2, 6, 4))
    assert features[0, :2].tolist() == pytest.approx([0.0, 1.0], abs=0.02)
    assert gate[0].item() > 0.95 and gate[1].item() < 1e-6


def test_the_heading_frame_says_who_is_ahead_and_a_car_at_rest_keeps_its_heading():
    nri = make("nri_trail", device="cpu")
    nri.mean, nri.std = np.zeros(4), np.ones(4)
    nri._build(3, 20)
    seen = torch.zeros(1, 4, 3, 4)  # [batch, frames, cars, (x, y, vx, vy)]
    seen[0, :, 0, 0] = torch.tensor([0.0, 1.0, 2.0, 2.0])  # car 0 drives along +x, then stops
    seen[0, 1:3, 0, 2] = 1.0
    seen[0, :, 1, 0] = 5.0  # car 1 stands ahead of it, car 2 to its left
    seen[0, :, 2, 1] = 3.0
    pairs = nri._heading_pairs(seen).view(1, 6, 4, 2)[0]
    seen_from_0 = {i: pairs[nri.pairs.index((i, 0))].tolist() for i in (1, 2)}
    # frame 0: car 0 has not moved yet, so no heading; frame 3: at rest, it keeps +x
    assert seen_from_0[1] == [[0.0, 0.0], [4.0, 0.0], [3.0, 0.0], [3.0, 0.0]]
    assert seen_from_0[2] == [[0.0, 0.0], [-1.0, 3.0], [-2.0, 3.0], [-2.0, 3.0]]
    # car 0 seen from a car that never moves: nothing
    assert pairs[nri.pairs.index((0, 1))].abs().sum() == 0


@pytest.mark.parametrize("types, skip_first", [(2, True), (1, False), (3, False)])
def test_the_batched_mlp_decoder_is_nri_s_loop(types, skip_first):
    seq, edges = inputs(types, 10 + types)
    decoder = MlpDecoder(4, 16, types, skip_first, SEND, RECV).double()
    assert_batched_is_the_loop(decoder, seq, None, edges)
    # No memory: a frame's prediction reads only the frame before it.
    changed = seq.clone()
    changed[:, 1] += 1.0
    a, b = decoder(seq, None, edges, truth_until=11), decoder(changed, None, edges, truth_until=11)
    assert torch.equal(a[:, 2:], b[:, 2:]) and not torch.equal(a[:, 1], b[:, 1])


def test_springs_integrate_alike_in_numpy_and_pytorch():
    numpy_run = springs.simulate(30, frames=20, seed=5)
    torch_run = springs.simulate(30, frames=20, seed=5, device="cpu")
    assert np.array_equal(numpy_run[2], torch_run[2])
    for a, b in zip(numpy_run[:2], torch_run[:2]):
        assert a.shape == b.shape and np.abs(a - b).max() < 1e-9


@pytest.mark.parametrize(
    "option, value, says",
    [("decoder", "gru", "use rnn, mlp or trail"), ("encoder_input", "cars", "use pairs, nodes, both or heading"),
     ("time_limit_s", 0, "seconds above 0")],
)  # fmt: skip
def test_nri_refuses_an_unknown_option_value(option, value, says):
    with pytest.raises(InputError, match=says):
        make("nri", device="cpu", **{option: value})


def test_the_trail_decoder_refuses_a_window_without_a_trail():
    with pytest.raises(InputError, match="window=1: the trail decoder needs a window of at least 2 frames"):
        make("nri", device="cpu", decoder="trail", window=1)


def test_a_time_limit_keeps_the_epochs_done():
    train = springs.episodes(20, frames=40, seed=1)
    nri = make("nri", epochs=50, batch_size=8, device="cpu", quiet=True, history=20, steps=5, warm=5, pair_every=2,
               window=4, warmup_epochs=0, time_limit_s=1e-6)  # fmt: skip
    nri.fit(train, None)
    assert len(nri.losses) == len(nri.epoch_seconds) == 1
    assert nri.predict(train).edges.shape == (20, 5, 5)


def test_a_model_wired_back_to_its_car_count_reads_the_tensors_it_trained_with():
    # A captured CUDA graph reads the very tensors it was captured with; each
    # epoch's val pass may wire the model to another car count and back, so
    # the decoder and encoder must get those same tensors back, not equal
    # copies whose memory the graph never sees (checked here on the CPU).
    train = springs.episodes(10, frames=40, seed=1)
    nri = make("nri", epochs=1, batch_size=8, device="cpu", quiet=True, history=20, steps=5, warm=5, pair_every=2,
               window=4, warmup_epochs=0)  # fmt: skip
    nri.fit(train, None)
    kept = (nri.decoder.grid_index, nri.decoder.send, nri.decoder.recv, nri.encoder.send, nri.encoder.recv)
    nri._wire(4)
    assert nri.decoder.grid_index.shape == (12,) and nri.decoder.grid_index is not kept[0]
    nri._wire(5)
    again = (nri.decoder.grid_index, nri.decoder.send, nri.decoder.recv, nri.encoder.send, nri.encoder.recv)
    assert all(a is b for a, b in zip(again, kept))


def test_springs_follow_nri_s_physics():
    positions, velocities, edges = springs.simulate(40, particles=5, frames=49, seed=4)
    assert positions.shape == velocities.shape == (40, 49, 5, 2) and edges.shape == (40, 5, 5)
    assert np.array_equal(edges, edges.transpose(0, 2, 1)) and not edges[:, range(5), range(5)].any()
    assert 0.4 < edges[:, ~np.eye(5, dtype=bool)].mean() < 0.6
    assert np.abs(positions).max() <= springs.BOX
    # Leapfrog with elastic walls conserves the energy the springs store and release.
    e = springs.energy(positions, velocities, edges)
    assert np.abs(e / e[:, :1] - 1).max() < 1e-3
    potential = e - 0.5 * (velocities**2).sum(axis=(-1, -2))
    assert potential.std(axis=1).mean() > 1e-3, "the springs do work"
    # A spring pulls its ends together: joined particles stay nearer than free ones.
    d = np.linalg.norm(positions[:, :, :, None] - positions[:, :, None, :], axis=-1)[:, 20:].mean(axis=1)
    off = ~np.eye(5, dtype=bool)
    assert d[:, off][edges[:, off] == 1].mean() < 0.95 * d[:, off][edges[:, off] == 0].mean()


def test_nri_finds_the_springs_well_above_chance():
    # About a minute on 2 CPU cores; the full figure is make bench-methods.
    train = springs.episodes(300, frames=69, seed=1)
    val = springs.episodes(50, frames=69, seed=2, split="val")
    test = springs.episodes(100, frames=69, seed=3, split="test")
    nri = make(
        "nri", epochs=8, batch_size=64, lr=2e-3, device="cpu", quiet=True, history=49, steps=10, warm=10,
        pair_every=1, window=10, warmup_epochs=2,
    )  # fmt: skip
    nri.fit(train, val)
    scores = nri.predict(test).edges
    # The encoder never sees a label; "spring" may come out as either edge type.
    auroc = auroc_of(scores, test.graph)
    assert max(auroc, 1 - auroc) > 0.75, auroc
    assert springs.edge_accuracy(scores, test.graph) > 0.65

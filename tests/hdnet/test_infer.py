"""MC-dropout inference: BN untouched, shared prefix == naive passes under the same masks, entropy."""

import math

import numpy as np
import pytest
import torch

from hdnet.errors import HdNetError
from hdnet.infer import mc_dropout_mode, mc_dropout_predict, mc_dropout_predict_naive, predictive_entropy
from hdnet.model import BayesianSegNet, ModelConfig


def _model() -> BayesianSegNet:
    torch.manual_seed(0)
    model = BayesianSegNet(width=1 / 16)
    model.train()
    with torch.no_grad():  # non-trivial running statistics
        for _ in range(3):
            model(torch.randn(4, 1, 32, 32))
    return model


class MaskInjector:
    """Forward hooks replacing each dropout's output by input * fixed mask / (1 - p).

    Masks are drawn once per module for M samples, shape (M, N, C, h, w). A call with batch k*N uses
    the next k samples' masks, sample-major: k = 1 on the naive path, k = M (or a chunk) when batched.
    """

    def __init__(self, model: BayesianSegNet, n: int, m: int, seed: int) -> None:
        self.n, self.m, self.gen = n, m, torch.Generator().manual_seed(seed)
        self.masks: dict[int, torch.Tensor] = {}
        self.calls: dict[int, int] = {}
        self.handles = [d.register_forward_hook(self.hook) for d in model.dropout_modules()]

    def hook(self, module, inputs, output):
        x = inputs[0]
        key = id(module)
        if key not in self.masks:
            shape = (self.m, self.n, *x.shape[1:])
            self.masks[key] = (torch.rand(shape, generator=self.gen) >= module.p).float()
        k = x.shape[0] // self.n
        start = self.calls.get(key, 0)
        self.calls[key] = start + k
        mask = self.masks[key][start : start + k].reshape(-1, *x.shape[1:])
        return x * mask / (1 - module.p)

    def remove(self) -> None:
        for h in self.handles:
            h.remove()


def test_sampling_leaves_batchnorm_statistics_and_modes_untouched() -> None:
    model = _model()
    model.train()
    before = {k: v.clone() for k, v in model.state_dict().items()}
    mc_dropout_predict(model, torch.randn(2, 1, 32, 32), n_samples=4)
    mc_dropout_predict_naive(model, torch.randn(2, 1, 32, 32), n_samples=2)
    after = model.state_dict()
    for key, value in before.items():
        assert torch.equal(value, after[key]), key
    assert all(m.training for m in model.modules())  # modes restored


def test_mode_inside_context_is_eval_except_dropout() -> None:
    model = _model().eval()
    with mc_dropout_mode(model) as net:
        for m in net.modules():
            assert m.training == (m in net.dropout_modules())
    assert not any(m.training for m in model.modules())


def test_sampling_runs_in_float32_proper_and_restores_the_tf32_flags() -> None:
    """On a GPU, TF32 convolutions moved P(safe) by up to 0.107 against the CPU and changed a best site
    (hdnet.infer's docstring): MC sampling switches TF32 off, and gives the user's flags back after."""
    model = _model().eval()
    flags = (torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32)
    try:
        torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = True, True
        with mc_dropout_mode(model):
            assert not torch.backends.cudnn.allow_tf32 and not torch.backends.cuda.matmul.allow_tf32
        assert torch.backends.cudnn.allow_tf32 and torch.backends.cuda.matmul.allow_tf32
        with pytest.raises(RuntimeError), mc_dropout_mode(model):
            raise RuntimeError("a failed pass")
        assert torch.backends.cudnn.allow_tf32 and torch.backends.cuda.matmul.allow_tf32
    finally:
        torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = flags


@pytest.mark.parametrize("chunk", [None, 3, 1])
def test_shared_prefix_equals_naive_under_same_masks(chunk) -> None:
    model = _model()
    x = torch.randn(2, 1, 40, 36)
    m = 5
    inj = MaskInjector(model, n=2, m=m, seed=1)
    naive = mc_dropout_predict_naive(model, x, n_samples=m)
    inj.calls.clear()
    shared = mc_dropout_predict(model, x, n_samples=m, samples_per_pass=chunk)
    assert all(c == m for c in inj.calls.values()) and len(inj.calls) == 6
    inj.remove()
    torch.testing.assert_close(shared.mean_probs, naive.mean_probs)
    assert torch.equal(shared.prediction, naive.prediction)
    torch.testing.assert_close(shared.entropy_nats, naive.entropy_nats)
    # The masks matter: without them the samples differ from this result.
    assert not torch.allclose(mc_dropout_predict(model, x, n_samples=m).mean_probs, naive.mean_probs)


def test_output_shapes_and_probabilities() -> None:
    out = mc_dropout_predict(_model(), torch.randn(3, 1, 32, 32), n_samples=4)
    assert out.mean_probs.shape == (3, 2, 32, 32) and out.prediction.shape == (3, 32, 32)
    torch.testing.assert_close(out.mean_probs.sum(1), torch.ones(3, 32, 32))
    assert (out.entropy_nats >= 0).all() and (out.entropy_nats <= math.log(2) + 1e-6).all()


def test_entropy_of_uniform_two_class_mean_is_ln2_and_certain_is_zero() -> None:
    p = torch.tensor([[0.5, 1.0], [0.5, 0.0]]).view(1, 2, 1, 2)
    h = predictive_entropy(p)
    torch.testing.assert_close(h, torch.tensor([[[math.log(2), 0.0]]]))
    q = torch.tensor([0.2, 0.8]).view(1, 2, 1, 1)
    expected = -(0.2 * math.log(0.2) + 0.8 * math.log(0.8))
    assert predictive_entropy(q).item() == pytest.approx(expected)


def test_bad_sample_count_raises() -> None:
    with pytest.raises(HdNetError):
        mc_dropout_predict(_model(), torch.randn(1, 1, 32, 32), n_samples=0)


class FixedSoftmaxes:
    """A forward hook on the classifier that makes sample k's softmax ``probs[k]`` at every pixel.

    The logits ln p give the softmax p. A call with batch k*N returns the next k samples, sample-major,
    as ``MaskInjector`` does: k = 1 on the naive path, k = M (or a chunk) with the shared prefix.
    """

    def __init__(self, model: BayesianSegNet, n: int, probs: list[list[float]]) -> None:
        self.n, self.logits, self.calls = n, torch.log(torch.tensor(probs)), 0
        self.handle = model.classifier.register_forward_hook(self.hook)

    def hook(self, module, inputs, output):
        k = output.shape[0] // self.n
        rows = self.logits[self.calls : self.calls + k].repeat_interleave(self.n, dim=0)
        self.calls += k
        return rows[:, :, None, None].expand_as(output).clone()


def entropy_of(p: list[float]) -> float:
    return -sum(q * math.log(q) for q in p if q > 0)


@pytest.mark.parametrize("path", ["shared", "naive"])
def test_mutual_information_of_two_opposite_samples_by_hand(path) -> None:
    """Samples [0.9, 0.1] and [0.1, 0.9]: mean [0.5, 0.5], H = ln 2, expected entropy H(0.9, 0.1)."""
    model = _model()
    fixed = FixedSoftmaxes(model, n=2, probs=[[0.9, 0.1], [0.1, 0.9]])
    x = torch.randn(2, 1, 32, 32)
    out = mc_dropout_predict(model, x, n_samples=2) if path == "shared" else mc_dropout_predict_naive(model, x, 2)
    fixed.handle.remove()
    assert fixed.calls == 2
    torch.testing.assert_close(out.mean_probs, torch.full_like(out.mean_probs, 0.5))
    h, expected = math.log(2), entropy_of([0.9, 0.1])
    torch.testing.assert_close(out.entropy_nats, torch.full((2, 32, 32), h))
    torch.testing.assert_close(out.expected_entropy_nats, torch.full((2, 32, 32), expected))
    torch.testing.assert_close(out.mutual_information_nats, torch.full((2, 32, 32), h - expected))


def test_expected_entropy_averages_unequal_samples_by_hand() -> None:
    """Three samples, one certain: expected entropy (H(0.8, 0.2) + 0 + H(0.5, 0.5)) / 3, chunked by 2."""
    model = _model()
    samples = [[0.8, 0.2], [1.0 - 1e-12, 1e-12], [0.5, 0.5]]
    fixed = FixedSoftmaxes(model, n=1, probs=samples)
    out = mc_dropout_predict(model, torch.randn(1, 1, 32, 32), n_samples=3, samples_per_pass=2)
    fixed.handle.remove()
    mean = [sum(p[c] for p in samples) / 3 for c in range(2)]
    expected = sum(entropy_of(p) for p in samples) / 3
    assert out.expected_entropy_nats[0, 0, 0].item() == pytest.approx(expected, abs=1e-6)
    assert out.mutual_information_nats[0, 0, 0].item() == pytest.approx(entropy_of(mean) - expected, abs=1e-6)


def test_mutual_information_is_zero_when_every_sample_is_the_same() -> None:
    x = torch.randn(2, 1, 32, 32)
    one = mc_dropout_predict(_model(), x, n_samples=1)  # one sample: H[p] - H[p]
    assert torch.equal(one.mutual_information_nats, torch.zeros(2, 32, 32))
    torch.manual_seed(0)
    no_dropout = BayesianSegNet(width=1 / 16, dropout_p=0.0)  # every sample the deterministic network
    for out in (mc_dropout_predict(no_dropout, x, n_samples=4), mc_dropout_predict_naive(no_dropout, x, 3)):
        torch.testing.assert_close(out.expected_entropy_nats, out.entropy_nats)
        assert (out.mutual_information_nats >= 0).all() and out.mutual_information_nats.max() < 1e-6


@pytest.mark.parametrize("chunk", [None, 2])
def test_mutual_information_shared_prefix_equals_naive_and_lies_in_zero_to_entropy(chunk) -> None:
    model = _model()
    x = torch.randn(2, 1, 40, 36)
    inj = MaskInjector(model, n=2, m=4, seed=2)
    naive = mc_dropout_predict_naive(model, x, n_samples=4)
    inj.calls.clear()
    shared = mc_dropout_predict(model, x, n_samples=4, samples_per_pass=chunk)
    inj.remove()
    torch.testing.assert_close(shared.expected_entropy_nats, naive.expected_entropy_nats)
    torch.testing.assert_close(shared.mutual_information_nats, naive.mutual_information_nats)
    for out in (shared, naive):
        mi = out.mutual_information_nats
        assert out.expected_entropy_nats.shape == mi.shape == (2, 40, 36)
        assert (mi >= 0).all() and (mi <= out.entropy_nats).all() and (mi > 0).any()  # the samples disagree


def test_on_grid_maps_probabilities_and_expected_entropy_and_recomputes_the_rest() -> None:
    out = mc_dropout_predict(_model(), torch.randn(1, 1, 32, 32), n_samples=3)

    def crop(t: torch.Tensor) -> torch.Tensor:
        return t[..., :20, :10]

    grid = out.on_grid(crop)
    torch.testing.assert_close(grid.mean_probs, crop(out.mean_probs))
    torch.testing.assert_close(grid.entropy_nats, crop(out.entropy_nats))
    torch.testing.assert_close(grid.expected_entropy_nats, crop(out.expected_entropy_nats))
    assert torch.equal(grid.prediction, crop(out.prediction)) and grid.mutual_information_nats.shape == (1, 20, 10)


# P(safe) of the pinned tiny run (seed 3, M = 4): the mean over both inputs and every seventh row's
# every sixth pixel of the first, as this code computed them (AMD EPYC, AVX-512, 2 threads).
PINNED_MEAN_P_SAFE = 0.5235825059314568
PINNED_P_SAFE = [0.5189439058303833, 0.5273343324661255, 0.5277044177055359, 0.5264042615890503,
                 0.5258278846740723, 0.5250556468963623, 0.5226631760597229, 0.5214920043945312]  # fmt: skip


def _pinned_run(seed: int) -> np.ndarray:
    """P(safe) (2, 24, 20) float32 of a seeded tiny network (width 1/16, depth 2, p = 0.5; weights
    from seed 0) on a fixed input made of integers (no transcendental function), M = 4."""
    torch.manual_seed(0)
    model = BayesianSegNet(ModelConfig(in_channels=1, width=1 / 16, depth=2, dropout_p=0.5)).eval()
    i = np.arange(24 * 20, dtype=np.int64)
    x = torch.from_numpy(((i * 7919 % 251) / 250.0 - 0.5).astype(np.float32)).view(1, 1, 24, 20)
    torch.manual_seed(seed)
    return mc_dropout_predict(model, torch.cat([x, x.flip(-1)]), n_samples=4).mean_probs[:, 1].numpy()


def test_a_tiny_runs_p_safe_is_pinned() -> None:
    """P(safe) of a seeded tiny run, pinned: any change of the masks (hdnet.dropout_masks: their bytes
    are pinned exactly in test_dropout_masks.py), the model or the arithmetic fails here.

    Not pinned bit for bit, and why: the masks are the same on every CPU by construction, but the
    float32 arithmetic is not. oneDNN picks its convolution kernels by the CPU's instruction set, and
    ATen its vectorised element-wise and reduction kernels, so the sums' order differs: on the
    development machine, ``ONEDNN_MAX_CPU_ISA=AVX2`` (instead of AVX-512) changed 3.8 % of these
    P(safe) values and ``ATEN_CPU_CAPABILITY=default`` 1.7 %, by at most 1.2e-7 (two ulp at 0.5),
    while thread counts 1 and 2 gave the same bits. Hence a tolerance of 1e-6 (~16 ulp): far below
    what another mask moves (another seed: 1e-3 to 5e-3 per pixel, 5e-5 on the mean). On one machine
    the run is bit for bit repeatable."""
    p = _pinned_run(3)
    assert np.array_equal(p, _pinned_run(3))  # repeatable, bit for bit, on one machine
    picked = p[:, ::7, ::6].ravel()[:8]
    np.testing.assert_allclose(picked, PINNED_P_SAFE, rtol=0, atol=1e-6)
    assert abs(float(p.astype(np.float64).mean()) - PINNED_MEAN_P_SAFE) < 1e-6
    other = _pinned_run(4)[:, ::7, ::6].ravel()[:8]  # the check can fail: another seed's masks
    assert np.abs(other - np.array(PINNED_P_SAFE)).max() > 1e-3

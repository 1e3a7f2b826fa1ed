"""hdnet.engine: the channels-last network draws the NCHW network's MC-dropout masks (hd's own), and
hd detect's maps with it equal the reference (NCHW) maps within float round-off."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from scipy import ndimage

from hdlabels.lander import Lander
from hdlabels.store import DemSpec, LabelingEntry
from hdnet.detect import DetectRun, detect_dem
from hdnet.detect_settings import LAYOUTS, DetectSettings
from hdnet.dropout_masks import keep_scale, sample_keep
from hdnet.engine import NCHWDrawDropout, inference_model, laid_out, predict_tile_by_tile
from hdnet.errors import HdNetError
from hdnet.fit import input_spec_for
from hdnet.infer import mc_dropout_predict
from hdnet.model import BayesianSegNet, MCDropout
from hdnet.profiles import ROBUST
from hdnet.run_record import CheckpointHeader

LABELING = LabelingEntry("l", Lander(), DemSpec(100, 100, 1.0))


def _model(width: float = 0.25) -> BayesianSegNet:
    """An untrained robust-profile network (narrow: seconds), BatchNorm statistics away from 0 / 1."""
    torch.manual_seed(0)
    spec = input_spec_for(ROBUST, 1.0, None)
    model = BayesianSegNet(replace(ROBUST, width=width).model_config(spec.n_channels)).eval()
    gen = torch.Generator().manual_seed(1)
    for m in model.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            assert m.running_mean is not None and m.running_var is not None
            m.running_mean.uniform_(-0.5, 0.5, generator=gen)
            m.running_var.uniform_(0.5, 2.0, generator=gen)
    return model


def test_nchw_draw_dropout_draws_hds_masks_in_either_layout():
    """While sampling, for the same seed, MCDropout and NCHWDrawDropout drop the cells of
    sample_keep's NCHW-order mask for a contiguous and for a channels-last input alike, bit for bit,
    and the output keeps the input's layout; a given mask is applied without a draw; in inference
    mode the input comes back."""
    x = torch.randn(3, 5, 7, 9)
    cl = x.contiguous(memory_format=torch.channels_last)
    torch.manual_seed(4)
    keep = sample_keep(x.shape, 0.2)
    reference = torch.where(keep, x * keep_scale(0.2), torch.tensor(0.0))  # kept cells scaled by 65536 / 52429
    assert 0.7 < keep.float().mean() < 0.9
    plain, drop = MCDropout(0.2).train(), NCHWDrawDropout(0.2).train()
    for layer in (plain, drop):
        layer.sampling = True
        for inp in (x, cl):
            torch.manual_seed(4)
            out = layer(inp)
            assert torch.equal(out, reference)
            assert out.is_contiguous(memory_format=torch.channels_last) == (inp is cl)
    torch.manual_seed(4)
    assert torch.equal(drop.draw(x.shape), keep)
    drop.mask = torch.stack([keep, ~keep], dim=1)[:, 0]  # a strided view, as predict_tile_by_tile gives
    state = torch.get_rng_state()
    assert torch.equal(drop(cl), reference) and torch.equal(torch.get_rng_state(), state)  # nothing drawn
    assert drop.eval()(x) is x


def test_inference_model_layouts():
    """nchw: the model itself; channels-last: a copy whose dropouts are NCHWDrawDropout (still
    MCDropout, so MC-dropout mode finds them) and whose weights are channels-last; others refused."""
    model = _model()
    assert inference_model(model, "nchw") is model
    fast = inference_model(model, "channels-last")
    drops = [m for m in fast.modules() if isinstance(m, MCDropout)]
    assert fast is not model and drops and all(isinstance(m, NCHWDrawDropout) for m in drops)
    assert len(drops) == len([m for m in model.modules() if isinstance(m, MCDropout)])
    conv = next(m for m in fast.modules() if isinstance(m, torch.nn.Conv2d))
    assert conv.weight.is_contiguous(memory_format=torch.channels_last)
    assert not any(isinstance(m, NCHWDrawDropout) for m in model.modules())  # the original is untouched
    with pytest.raises(HdNetError, match="unknown network layout"):
        inference_model(model, "nhwc")
    with pytest.raises(HdNetError):
        DetectSettings(layout="nhwc")
    assert LAYOUTS == ("channels-last", "channels-last-per-tile", "nchw") and DetectSettings().layout == "channels-last"
    with pytest.raises(HdNetError, match="inference_model"):
        predict_tile_by_tile(model, torch.zeros(1, model.config.in_channels, 8, 8), 2)


def test_mc_dropout_with_channels_last_equals_nchw():
    """The same seed gives the same MC samples: mean softmax and entropies within 1e-5."""
    model = _model()
    x = torch.randn(3, model.config.in_channels, 40, 40)
    torch.manual_seed(7)
    ref = mc_dropout_predict(model, x, n_samples=5)
    fast = inference_model(model, "channels-last")
    torch.manual_seed(7)
    out = mc_dropout_predict(fast, laid_out(x, "channels-last"), n_samples=5)
    torch.testing.assert_close(out.mean_probs, ref.mean_probs, rtol=0, atol=1e-5)
    torch.testing.assert_close(out.entropy_nats, ref.entropy_nats, rtol=0, atol=1e-5)
    torch.testing.assert_close(out.expected_entropy_nats, ref.expected_entropy_nats, rtol=0, atol=1e-5)
    torch.manual_seed(7)
    per_tile = predict_tile_by_tile(fast, laid_out(x, "channels-last"), 5)  # each input alone, the batch's masks
    torch.testing.assert_close(per_tile.mean_probs, ref.mean_probs, rtol=0, atol=1e-5)
    torch.testing.assert_close(per_tile.entropy_nats, ref.entropy_nats, rtol=0, atol=1e-5)
    torch.testing.assert_close(per_tile.expected_entropy_nats, ref.expected_entropy_nats, rtol=0, atol=1e-5)
    assert torch.equal(per_tile.prediction, per_tile.mean_probs.argmax(dim=1))
    torch.manual_seed(8)  # another seed: other samples (the masks matter at this tolerance)
    other = mc_dropout_predict(fast, laid_out(x, "channels-last"), n_samples=5)
    assert (other.mean_probs - ref.mean_probs).abs().max() > 1e-3


def test_detect_maps_with_channels_last_equal_the_reference_maps():
    """detect_dem of a 150 x 150 DTM (four tiles, a nodata hole) with each layout: the same valid
    cells, P(safe), entropy, mutual information and baseline within 1e-3 (float round-off: ~1e-6)."""
    model = _model()
    spec = input_spec_for(ROBUST, 1.0, None)
    run = DetectRun(
        Path("-"), model, CheckpointHeader(0, None, None), 0.0167, spec, "l", LABELING, Lander(), (100, 100), 1.0, None
    )
    rng = np.random.default_rng(5)
    z = ndimage.gaussian_filter(rng.normal(0, 1.0, (150, 150)), 3)
    z[60:70, 20:90] = np.nan
    options: dict[str, Any] = {"threshold": "nats:0.3", "mc_samples": 4, "seed": 1, "n_sites": 2, "batch_size": 3}
    ref = detect_dem(run, z, layout="nchw", **options)
    for layout in ("channels-last", "channels-last-per-tile"):
        fast = detect_dem(run, z, layout=layout, **options)
        assert np.array_equal(ref.valid, fast.valid) and ref.valid.sum() > 10_000
        for name in ("p_safe", "entropy_nats", "mutual_information_nats", "baseline_p_safe"):
            a, b = getattr(ref, name), getattr(fast, name)
            assert np.nanmax(np.abs(a - b)) < 1e-3, (layout, name)
    assert np.nanstd(ref.p_safe) > 1e-3  # the maps vary: the comparison can fail

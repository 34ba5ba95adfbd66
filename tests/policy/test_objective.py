"""The method's maths, each piece alone: DCT, Parseval, the proximal window, samplers, ablation switches."""

import dataclasses

import numpy as np
import pytest
import scipy.fft
import torch

from lerobot_focal.policy.ablations import get_switch
from lerobot_focal.policy.configuration_focal import ABLATIONS, FocalConfig, FocalConfigError
from lerobot_focal.policy.method_groups import AnchorConfig
from lerobot_focal.policy.objective import (
    ObjectiveSpec,
    composite_loss,
    consistency_loss,
    dct,
    frequency_loss,
)
from lerobot_focal.policy.time_samplers import TimeSamplerSpec, sample_times

L, H, D, B = 12, 4, 5, 16


def test_dct_matches_scipy_orthonormal_dct2():
    x = torch.randn(3, L, D, dtype=torch.float64)
    ours = dct(x, dim=1).numpy()
    ref = scipy.fft.dct(x.numpy(), type=2, norm="ortho", axis=1)
    np.testing.assert_allclose(ours, ref, atol=1e-12)


def test_parseval_freq_loss_equals_summed_squared_time_error():
    pred, target = torch.randn(B, L, D, dtype=torch.float64), torch.randn(B, L, D, dtype=torch.float64)
    l_freq = frequency_loss(pred, target, ObjectiveSpec(chunk_size=H))
    summed = (pred - target).pow(2).sum(dim=(1, 2)).mean()
    torch.testing.assert_close(l_freq, summed)


def _grad_of_time_loss(spec: ObjectiveSpec) -> torch.Tensor:
    f_tau = torch.randn(B, L, D, requires_grad=True)
    f_r, m1 = torch.randn(B, L, D), torch.randn(B, L, D)
    loss, _ = composite_loss(f_tau, f_r, m1, dataclasses.replace(spec, regularizer="none"))
    loss.backward()
    return f_tau.grad


def test_time_loss_gradient_is_zero_outside_the_proximal_chunk():
    grad = _grad_of_time_loss(ObjectiveSpec(chunk_size=H))
    assert grad[:, H:].abs().max() == 0
    assert grad[:, :H].abs().min() > 0


def test_fco_full_macro_supervises_all_steps():
    grad = _grad_of_time_loss(ObjectiveSpec(chunk_size=H, time_window="macro"))
    assert grad.abs().min() > 0


def test_time_loss_is_mean_and_freq_loss_is_sum():
    f_tau, f_r, m1 = torch.ones(B, L, D), torch.zeros(B, L, D), torch.zeros(B, L, D)
    _, logs = composite_loss(f_tau, f_r, m1, ObjectiveSpec(chunk_size=H))
    assert logs["loss_time"].item() == pytest.approx(1.0)
    assert logs["loss_freq"].item() == pytest.approx(L * D, rel=1e-5)


def test_las_anchor_distribution_matches_the_paper():
    g = torch.Generator().manual_seed(0)
    _, r = sample_times(TimeSamplerSpec(), 400_000, generator=g)
    assert r.median().item() == pytest.approx(0.982, abs=0.002)
    # "~95 % of the mass in [0.5, 1]": the central 95 % interval lies inside [0.5, 1] (it is ≈ [0.70, 0.999]);
    # the exact mass above 0.5 is Φ(4.0 / 1.6) = Φ(2.5) ≈ 0.9938.
    lo, hi = torch.quantile(r[:100_000], torch.tensor([0.025, 0.975])).tolist()
    assert 0.5 <= lo and hi <= 1.0
    assert lo == pytest.approx(torch.sigmoid(torch.tensor(4.0 - 1.96 * 1.6)).item(), abs=0.01)
    assert (r >= 0.5).float().mean().item() == pytest.approx(0.9938, abs=0.001)


def test_flow_time_is_uniform_on_eps_1():
    tau, _ = sample_times(TimeSamplerSpec(eps=0.01), 200_000, generator=torch.Generator().manual_seed(1))
    assert tau.min() >= 0.01 and tau.max() <= 1
    assert tau.mean().item() == pytest.approx(0.505, abs=0.003)


def test_adjacent_and_fixed_and_mixture_samplers():
    g = torch.Generator().manual_seed(2)
    tau, r = sample_times(TimeSamplerSpec(kind="adjacent", adjacent_delta=0.05), 1000, generator=g)
    torch.testing.assert_close(r, torch.clamp(tau + 0.05, max=1.0))
    _, r = sample_times(TimeSamplerSpec(kind="fixed"), 100, generator=g)
    assert torch.all(r == 1.0)
    _, r = sample_times(TimeSamplerSpec(kind="mixture"), 400_000, generator=g)
    # The authors' public code: median ≈ 0.976 (REFERENCES §0), lower than pure LAS.
    assert r.median().item() == pytest.approx(0.976, abs=0.003)


def test_unknown_sampler_and_switch_values_are_rejected_with_the_choices():
    with pytest.raises(ValueError, match="logit_normal"):
        TimeSamplerSpec(kind="uniform")
    with pytest.raises(ValueError, match="proximal"):
        ObjectiveSpec(time_window="chunk")


@pytest.mark.parametrize("name", sorted(ABLATIONS))
def test_each_ablation_changes_exactly_the_fields_it_names(name):
    base, ablated = FocalConfig(), FocalConfig(ablation=name)

    def leaves(config):  # every field, a group's as "group.field"
        for f in dataclasses.fields(config):
            value = getattr(config, f.name)
            if dataclasses.is_dataclass(value):
                yield from ((f"{f.name}.{k}", v) for k, v in dataclasses.asdict(value).items())
            elif f.name != "ablation":
                yield f.name, value

    ablated_values = dict(leaves(ablated))
    changed = {name for name, value in leaves(base) if ablated_values[name] != value}
    expected = {k for k, v in ABLATIONS[name].items() if get_switch(base, k) != v}
    assert changed == expected and expected


def test_ablation_conflicting_with_an_explicit_field_is_an_error():
    with pytest.raises(FocalConfigError, match="anchor.kind"):
        FocalConfig(ablation="wo_las", anchor=AnchorConfig(kind="mixture"))
    with pytest.raises(FocalConfigError, match="Unknown ablation 'nope'"):
        FocalConfig(ablation="nope")


def test_band_switches_select_disjoint_coefficients():
    pred, target = torch.randn(B, L, D, dtype=torch.float64), torch.zeros(B, L, D, dtype=torch.float64)
    full = frequency_loss(pred, target, ObjectiveSpec(chunk_size=H))
    low = frequency_loss(pred, target, ObjectiveSpec(chunk_size=H, freq_band="low"))
    high = frequency_loss(pred, target, ObjectiveSpec(chunk_size=H, freq_band="high"))
    torch.testing.assert_close(low + high, full)
    # A constant error lives only in the DC coefficient.
    const = torch.ones(B, L, D, dtype=torch.float64)
    assert frequency_loss(const, target, ObjectiveSpec(chunk_size=H, freq_band="high")).item() < 1e-20


def test_prox_freq_window_only_sees_the_first_chunk():
    pred, target = torch.zeros(B, L, D), torch.zeros(B, L, D)
    pred[:, H:] = 1.0
    assert frequency_loss(pred, target, ObjectiveSpec(chunk_size=H, freq_window="proximal")).item() == 0
    assert frequency_loss(pred, target, ObjectiveSpec(chunk_size=H)).item() > 0


def _linear_velocity(weight: torch.Tensor):
    return lambda m, t: weight * m


def test_consistency_loss_target_is_called_without_grad_and_skipped_when_r_is_one():
    m0, m1 = torch.randn(B, L, D), torch.randn(B, L, D)
    tau = torch.full((B,), 0.5)
    w = torch.tensor(0.3, requires_grad=True)
    calls = []

    def target(m, t):
        calls.append(torch.is_grad_enabled())
        return w * m

    spec = ObjectiveSpec(chunk_size=H)
    consistency_loss(spec, m0, m1, tau, torch.full((B,), 0.9), _linear_velocity(w), target)
    assert calls == [False]
    calls.clear()
    loss, _ = consistency_loss(spec, m0, m1, tau, torch.ones(B), _linear_velocity(w), target)
    assert calls == []  # f(M_1, 1) = M_1: no network evaluation needed
    # With r = 1 the proximal target is the expert chunk itself.
    m_tau = 0.5 * m0 + 0.5 * m1
    f_tau = m_tau + 0.5 * 0.3 * m_tau
    expected = (f_tau - m1)[:, :H].pow(2).flatten(1).mean(1).mean() + 1e-4 * (f_tau - m1).pow(2).sum((1, 2)).mean()
    torch.testing.assert_close(loss, expected)


def test_freq_only_drops_time_loss_and_time_only_replaces_the_regulariser():
    f_tau, f_r, m1 = torch.randn(B, L, D), torch.randn(B, L, D), torch.randn(B, L, D)
    _, logs = composite_loss(f_tau, f_r, m1, ObjectiveSpec(chunk_size=H, time_weight=0.0))
    assert set(logs) == {"loss_freq"}
    loss, logs = composite_loss(f_tau, f_r, m1, ObjectiveSpec(chunk_size=H, regularizer="time_mse"))
    assert set(logs) == {"loss_time", "loss_macro_mse"}
    torch.testing.assert_close(loss, logs["loss_time"] + logs["loss_macro_mse"])


def test_flowpolicy_objective_uses_segment_ends():
    m0, m1 = torch.randn(B, L, D), torch.randn(B, L, D)
    tau = torch.full((B,), 0.3)  # segment end 0.5 with two segments
    r = torch.full((B,), 0.31)
    zero = lambda m, t: torch.zeros_like(m)  # noqa: E731
    loss, logs = consistency_loss(ObjectiveSpec(kind="flowpolicy"), m0, m1, tau, r, zero, zero)
    # v = 0 → f_τ = M_τ and f_r = M_r: the loss is the squared distance between the two interpolants.
    expected = (0.01 * (m1 - m0)).pow(2).flatten(1).mean(1).mean()
    torch.testing.assert_close(logs["loss_consistency"], expected)

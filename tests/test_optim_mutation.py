"""4th-seed mutation operators (ICGO eqs. 15-18) against closed forms."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import icgo  # noqa: F401
from icgo.optim import mutation as mut
from icgo.optim.cgo import CGOConfig, mean_groups
from icgo.optim.registry import get


def _period(seq):
    """Distance back to the last earlier occurrence of the final value (exact), or 0."""
    idx = np.flatnonzero(seq[:-1] == seq[-1])
    if not len(idx):
        return 0
    p = len(seq) - 1 - idx[-1]
    return p if np.array_equal(seq[-1 - p - 50:-1 - p], seq[-51:-1]) else 0


def _iterate(r0, n, guard, dtype):
    step = jax.jit(lambda k, r: mut.logistic_step(k, r, jnp.asarray(4.0, dtype), guard))
    keys = jax.random.split(jax.random.key(0), n)

    def body(r, k):
        r = step(k, r)
        return r, r

    _, seq = jax.lax.scan(body, jnp.asarray(r0, dtype), keys)
    return np.asarray(seq)


def test_logistic_float32_cycles_without_guard_not_with_it():
    starts = [0.1234, 0.31, 0.77]
    bare = [_period(_iterate(r0, 12000, False, jnp.float32)) for r0 in starts]
    guarded = [_period(_iterate(r0, 12000, True, jnp.float32)) for r0 in starts]
    assert all(0 < p <= 4344 for p in bare), bare  # the bare float32 map falls into a short cycle (ENGINEERING-NOTES)
    assert all(p == 0 for p in guarded), guarded
    seq = _iterate(0.1234, 6000, True, jnp.float32)
    assert np.all((seq > 0) & (seq < 1))
    assert len(np.unique(seq[-2000:])) > 1900


def test_logistic_step_closed_form_in_float64():
    r = jnp.array([0.2, 0.6])
    np.testing.assert_allclose(np.asarray(mut.logistic_step(jax.random.key(0), r, 3.8, False)), 3.8 * r * (1 - r))
    g = np.asarray(mut.logistic_step(jax.random.key(0), r, 3.8, True))
    np.testing.assert_allclose(g, 3.8 * np.asarray(r) * (1 - np.asarray(r)), atol=1e-13)


def test_wavelet_dilation_and_amplitude():
    g, zeta, T = 10000.0, 5.0, 100
    assert float(mut.wavelet_dilation(0, T, g, zeta)) == pytest.approx(1.0)
    assert float(mut.wavelet_dilation(T, T, g, zeta)) == pytest.approx(g)
    a = np.asarray(mut.wavelet_dilation(jnp.arange(T + 1), T, g, zeta))
    assert np.all(np.diff(a) >= 0)
    assert float(mut.wavelet_dilation(50, T, g, zeta)) == pytest.approx(np.exp(-np.log(g) * 0.5**zeta + np.log(g)))
    for a_ in (1.0, 100.0):
        s = np.asarray(mut.wavelet_sigma(jax.random.key(1), (4000,), a_, jnp.float64))
        assert np.abs(s).max() <= a_**-0.5 + 1e-15
        assert np.abs(s).max() > 0.9 * a_**-0.5  # psi(0) = 1 is reached
    np.testing.assert_allclose(float(mut.morlet(0.3)), np.exp(-0.045) * np.cos(1.5))


def test_three_stage_schedule_thirds_and_custom():
    T = 30
    eff = [int(mut.effective_strategy(4, t, T, (1 / 3, 2 / 3), (1, 2, 3))) for t in range(T)]
    assert eff[:10] == [1] * 10 and eff[10:20] == [2] * 10 and eff[20:] == [3] * 10
    eff = [int(mut.effective_strategy(4, t, T, (0.5, 0.9), (3, 0, 1))) for t in range(T)]
    assert eff[:15] == [3] * 15 and eff[15:27] == [0] * 12 and eff[27:] == [1] * 3
    assert int(mut.effective_strategy(2, 29, T, (1 / 3, 2 / 3), (1, 2, 3))) == 2


def test_dims_mask_modes():
    k = jax.random.key(3)
    m = np.asarray(mut.dims_mask(k, (500, 6), "subset"))
    assert m.sum(1).min() >= 1 and m.sum(1).max() == 6
    assert set(np.unique(m.sum(1))) == set(range(1, 7))  # sizes U{1..D}
    assert np.asarray(mut.dims_mask(k, (5, 6), "all")).all()
    np.testing.assert_array_equal(np.asarray(mut.dims_mask(k, (5, 6), "one")).sum(1), 1)
    with pytest.raises(ValueError, match="unknown dims mode"):
        mut.dims_mask(k, (5, 6), 1)  # a static name, not an index


@pytest.mark.parametrize("strategy", [0, 1, 2, 3])
def test_mutate_operators(strategy):
    cfg = CGOConfig()
    P, D = 4000, 3
    x = jnp.zeros((P, D)) + 5.0
    mask = jnp.zeros((P, D), bool).at[:, 0].set(True)
    r = jnp.full((P, D), 0.25)
    lb, ub = -100.0 * jnp.ones(D), 100.0 * jnp.ones(D)
    s = np.asarray(mut.mutate(jax.random.key(9), x, mask, r, strategy, 10, 100, lb, ub, cfg))
    np.testing.assert_array_equal(s[:, 1:], 5.0)  # unmasked coordinates untouched
    d = s[:, 0] - 5.0
    if strategy == 0:  # eq. 15: + U(0, 1)
        assert d.min() >= 0 and d.max() <= 1 and abs(d.mean() - 0.5) < 0.03
    elif strategy == 1:  # eq. 17: + r_t
        np.testing.assert_allclose(d, 0.25)
    elif strategy == 2:  # eq. 16: + N(0, sigma^2)
        assert abs(d.mean()) < 0.06 and abs(d.std() - cfg.sigma) < 0.05
    else:  # eq. 18 with a(10/100)
        a = float(mut.wavelet_dilation(10, 100, cfg.wavelet_g, cfg.wavelet_zeta))
        assert np.abs(d).max() <= a**-0.5 + 1e-12


def test_matlab_original_seed_is_uniform_point():
    cfg = CGOConfig.matlab()
    assert cfg.original_uniform is True
    x = jnp.zeros((2000, 2))
    s = np.asarray(mut.mutate(jax.random.key(2), x, jnp.zeros((2000, 2), bool), x, 0, 0, 10,
                              jnp.array([-1.0, 10.0]), jnp.array([1.0, 20.0]), cfg))
    assert s[:, 0].min() >= -1 and s[:, 0].max() <= 1 and s[:, 1].min() >= 10 and s[:, 1].max() <= 20
    assert abs(s[:, 1].mean() - 15) < 0.3


def test_mean_groups_are_means_of_random_subsets():
    P = 9
    w = np.asarray(mean_groups(jax.random.key(0), jnp.eye(P)))  # MG_i = weights of row i
    np.testing.assert_allclose(w.sum(1), 1.0)
    for row in w:
        nz = row[row > 0]
        np.testing.assert_allclose(nz, 1.0 / len(nz))


def test_mean_groups_of_fixed_size():
    """mealpy's MG: the mean of exactly 3 distinct seeds; a size above N is capped at N."""
    P = 9
    w = np.asarray(mean_groups(jax.random.key(1), jnp.eye(P), 3))
    np.testing.assert_allclose(np.sort(w, axis=1)[:, -3:], 1.0 / 3)
    np.testing.assert_array_equal((w > 0).sum(1), 3)
    np.testing.assert_allclose(np.asarray(mean_groups(jax.random.key(1), jnp.eye(P), 50)), 1.0 / P)


def test_mealpy_alphas_ranges():
    from icgo.optim.cgo import _alphas_mealpy

    a = np.asarray(_alphas_mealpy(jax.random.key(3), 20000, jnp.float64))[..., 0]
    assert a.shape == (20000, 3)
    assert a[:, 0].min() >= 0 and a[:, 0].max() < 1 and a[:, 1].max() < 2 and a[:, 2].min() >= 1
    np.testing.assert_allclose(a.mean(0), [0.5, 1.0, 1.25], atol=0.01)  # E[1 + U U] = 1.25


def test_strategy_index_names():
    assert [mut.strategy_index(s) for s in mut.STRATEGIES] == [0, 1, 2, 3, 4]
    with pytest.raises(ValueError, match="unknown strategy"):
        mut.strategy_index(7)


def test_stage_clock_restarts_the_wavelet_schedule_in_each_stage():
    """Issue 18: a three-stage wavelet on its own stage clock sweeps its whole dilation schedule."""
    T, b = 90, (1 / 3, 2 / 3)
    t_w, T_w = mut.stage_clock(4, 75, T, b)  # third stage: starts at 60, lasts 30
    assert float(t_w) == pytest.approx(15.0) and float(T_w) == pytest.approx(30.0)
    assert tuple(float(v) for v in mut.stage_clock(3, 75, T, b)) == (75.0, 90.0)  # a single strategy: the run's clock
    t_w, T_w = mut.stage_clock(4, 5, T, (0.1, 0.4))  # first stage of 10/30/60
    assert (float(t_w), float(T_w)) == pytest.approx((5.0, 9.0))
    # the dilation at the stage's start is the schedule's start (a = 1), not the run's late value
    a_stage = float(mut.wavelet_dilation(*mut.stage_clock(4, 60, T, b), 10000.0, 5.0))
    a_run = float(mut.wavelet_dilation(60, T, 10000.0, 5.0))
    assert a_stage == pytest.approx(1.0) and a_run > 100.0


def test_cgo_stage_clock_reaches_the_three_stage_search():
    import jax
    import numpy as np

    from icgo.optim import run
    from icgo.optim.cgo import CGOConfig

    def rastrigin(pop, aux=None):  # many local minima: the 4th seed's step size shows in the result
        x = 5.12 * pop
        return jax.numpy.sum(x ** 2 - 10 * jax.numpy.cos(2 * jax.numpy.pi * x) + 10, axis=1)

    box = (np.full(6, -1.0), np.full(6, 1.0))
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    # (for a single strategy the clock is the run's, tested above; the compiled programs differ, so
    # its results may differ in the last bits and are not compared here)
    a = [run(get("cgo"), rastrigin, box, k, 10, 60, config=CGOConfig.paper(strategy="three_stage")) for k in keys]
    b = [run(get("cgo"), rastrigin, box, k, 10, 60, config=CGOConfig.paper(strategy="three_stage", wavelet_stage_clock=True))
         for k in keys]
    assert not all(np.array_equal(np.asarray(x.best_x), np.asarray(y.best_x)) for x, y in zip(a, b))
    with pytest.raises(ValueError, match="wavelet_stage_clock must be True or False"):
        CGOConfig.paper(strategy="three_stage", wavelet_stage_clock="yes")


def test_wavelet_amplitude_reading():
    """Issue 18 sweep 2: without Ling's a^(-1/2) the step is the Morlet value alone, whatever the dilation."""
    key = jax.random.key(3)
    for a in (1.0, 100.0, 1e4):
        ling = np.asarray(mut.wavelet_sigma(key, (2000,), a, jnp.float64))
        none = np.asarray(mut.wavelet_sigma(key, (2000,), a, jnp.float64, "none"))
        np.testing.assert_allclose(ling, none / np.sqrt(a), rtol=1e-12)
        assert np.abs(none).max() <= 1.0 and np.abs(none).max() > 0.9
    with pytest.raises(ValueError, match="unknown CGO wavelet_amplitude 'half'"):
        CGOConfig.paper(wavelet_amplitude="half")


# --- the registry: a strategy is a function registered by name ------------------------------------------------


def _levy_like(key, s, amplitude=0.5):
    """A user's operator: x + amplitude * sign * U(0, 1)^2 on the masked coordinates (closed form below)."""
    k_u, k_s = jax.random.split(key)
    u = jax.random.uniform(k_u, s.x.shape, s.x.dtype)
    sign = jnp.where(jax.random.bernoulli(k_s, 0.5, s.x.shape), 1.0, -1.0)
    return jnp.where(s.mask, s.x + amplitude * sign * u * u, s.x)


def test_registry_holds_the_papers_five_in_index_order():
    assert mut.STRATEGIES == ("original", "chaos", "gaussian", "wavelet", "three_stage")
    assert tuple(mut.MUTATIONS)[:5] == mut.STRATEGIES
    assert [mut.MUTATIONS[s].operator is not None for s in mut.STRATEGIES] == [True] * 4 + [False]
    assert mut.STAGE_ORDER == (1, 2, 3) and CGOConfig().stage_order == (1, 2, 3)
    from icgo.studies.icgo_relm.names import STRATEGY_NAMES, method_name

    assert STRATEGY_NAMES == {s: mut.MUTATIONS[s].label for s in mut.STRATEGIES}
    assert method_name("cgo-gaussian") == "ICGO-RELM (Gaussian)"


@pytest.fixture
def own_registry():
    """The registry as shipped, restored in place after the test (its registrations are the test's only)."""
    before = dict(mut.MUTATIONS)
    yield mut.MUTATIONS
    mut.MUTATIONS.clear()
    mut.MUTATIONS.update(before)


def test_register_refuses_bad_names_and_a_taken_name(own_registry):
    with pytest.raises(ValueError, match="lower-case identifier"):
        mut.register("Levy-1", _levy_like)
    with pytest.raises(ValueError, match="must be a function"):
        mut.register("levy", "not a function")
    with pytest.raises(ValueError, match="already registered with another operator"):
        mut.register("chaos", _levy_like)
    from functools import partial

    i = mut.register("levy", partial(_levy_like, amplitude=0.25), "Levy-like")
    assert i == 5 and mut.register("levy", partial(_levy_like, amplitude=0.25), "Levy-like") == 5  # same: a no-op
    with pytest.raises(ValueError, match="already registered"):
        mut.register("levy", partial(_levy_like, amplitude=0.5), "Levy-like")


def test_a_registered_strategy_runs_batched_beside_the_builtins_which_keep_their_bits(own_registry):
    """A user's operator, by name, in one vmapped batch with the five built-ins: its seeds are its closed form,
    and the built-ins' results are bitwise those of the batch without it (its branch only adds a branch)."""
    from icgo.optim import run_batch
    from icgo.optim.cgo import CGO

    def sphere(pop, aux):
        return jnp.sum((pop - aux) ** 2, axis=-1)

    box = (-5.0 * jnp.ones(3), 5.0 * jnp.ones(3))
    keys = jax.random.split(jax.random.key(3), 2)
    aux = jnp.ones((2, 3))
    before = run_batch(get("cgo"), sphere, box, keys, 8, 6, configs=CGO.axis_configs(None, mut.STRATEGIES), aux=aux)
    mut.register("levy_like", _levy_like, "Levy-like")
    configs = CGO.axis_configs(None, (*mut.STRATEGIES, "levy_like"))
    assert configs[-1].strategy == 5 and configs[0].mutations == (*mut.STRATEGIES, "levy_like")
    after = run_batch(get("cgo"), sphere, box, keys, 8, 6, configs=configs, aux=aux)
    assert after.best_f.shape == (6, 2)
    np.testing.assert_array_equal(np.asarray(after.best_f[:5]), np.asarray(before.best_f))
    np.testing.assert_array_equal(np.asarray(after.curve[:5]), np.asarray(before.curve))
    assert np.all(np.isfinite(np.asarray(after.best_f[5])))
    # the operator itself through mutate's switch: x + 0.5 sign u^2 on the mask, |d| <= 0.5, mean |d| = 0.5 / 3
    P, D = 6000, 2
    x = jnp.full((P, D), 1.0)
    mask = jnp.zeros((P, D), bool).at[:, 1].set(True)
    s4 = np.asarray(mut.mutate(jax.random.key(1), x, mask, x, 5, 0, 10, box[0][:2], box[1][:2], configs[-1]))
    d = s4[:, 1] - 1.0
    np.testing.assert_array_equal(s4[:, 0], 1.0)
    assert np.abs(d).max() <= 0.5 and abs(np.abs(d).mean() - 0.5 / 3) < 0.01 and abs(d.mean()) < 0.01
    with pytest.raises(ValueError, match="stage_order must name 3 single strategies"):
        CGOConfig(stage_order=("chaos", "gaussian", "three_stage"))
    assert CGOConfig(strategy="three_stage", stage_order=("chaos", "levy_like", "wavelet")).stage_order == (1, 5, 3)

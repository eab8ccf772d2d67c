"""PPO's minibatch steps for small vector networks as one numba-compiled function.

`mlp_update`'s NumPy path spends most of a gradient step in NumPy's per-call overhead: ~80 small
operations on 64-wide arrays, ~0.5 ms a step where the arithmetic needs ~0.05 ms. Here a whole epoch of
minibatches runs in one compiled call on flat float32 buffers: the forward passes, the clipped surrogate,
the value loss, the entropy bonus, the backward passes and Adam, with the products done by BLAS
(`np.dot` into preallocated arrays; numba calls SciPy's BLAS). It computes what the NumPy path computes
(`mlp_update.policy_head_grad`, `value_head_grad`, `Adam`), sample by sample; the tests hold both to
torch's autograd and Adam step by step.

Layout. `flat` holds every parameter (policy layers, the log-std of a continuous policy, value layers),
each torch weight [out, in] row-major; `grads`, `m`, `v` are the same size. A network is described by an
int64 table, one row per Linear layer: (weight offset, bias offset, inputs, outputs), ReLU after every
layer but the last. Per-sample scalars are float64; arrays stay float32.

Compiled with `cache=True`: the first use on a machine compiles (a few seconds, measured in
docs/learner.md), later processes load the cached machine code.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from racerlab.agent.distributions import PPO_LOG_STD_MAX, PPO_LOG_STD_MIN, PROB_FLOOR

_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)
HISTORY_COLUMNS = 5  # pg_loss, v_loss, entropy, approx_kl, clipfrac per step
# NumPy's error model: a float division by zero gives inf instead of raising, and without that check in every
# division LLVM vectorises the loops (Adam's went from 20 to 5 µs for 12 k weights). No fastmath: the order and
# rounding of every operation are IEEE's.
_compiled = njit(cache=True, error_model="numpy")
_SMALLEST_NORMAL = np.float32(np.finfo(np.float32).tiny)


@_compiled
def _view(buf, offset, rows, cols):
    return buf[offset:offset + rows * cols].reshape(rows, cols)


@_compiled
def _forward(flat, layers, acts, act_offsets, mb):
    """acts[k + 1] = relu(acts[k] @ W_k.T + b_k) (no ReLU after the last layer); acts[0] is the input."""
    n = layers.shape[0]
    for k in range(n):
        w_off, b_off, d_in, d_out = layers[k, 0], layers[k, 1], layers[k, 2], layers[k, 3]
        a = _view(acts, act_offsets[k], mb, d_in)
        h = _view(acts, act_offsets[k + 1], mb, d_out)
        np.dot(a, _view(flat, w_off, d_out, d_in).T, h)
        relu = k < n - 1
        for i in range(mb):
            for o in range(d_out):
                z = h[i, o] + flat[b_off + o]
                h[i, o] = 0.0 if (relu and z < 0.0) else z  # NaN passes, as torch's ReLU lets it


@_compiled
def _backward(flat, grads, layers, acts, act_offsets, g_top, work, mb):
    """dL/dW, dL/db of every layer into `grads` from dL/d(output) `g_top` [mb, outputs] (overwritten);
    `work` is scratch of at least mb × the widest layer, twice."""
    n = layers.shape[0]
    half = work.shape[0] // 2
    g = g_top
    for k in range(n - 1, -1, -1):
        w_off, b_off, d_in, d_out = layers[k, 0], layers[k, 1], layers[k, 2], layers[k, 3]
        a = _view(acts, act_offsets[k], mb, d_in)
        np.dot(g.T, a, _view(grads, w_off, d_out, d_in))
        for o in range(d_out):
            grads[b_off + o] = 0.0
        for i in range(mb):
            for o in range(d_out):
                grads[b_off + o] += g[i, o]
        if k:
            g_in = _view(work, half * (k % 2), mb, d_in)
            np.dot(g, _view(flat, w_off, d_out, d_in), g_in)
            for i in range(mb):
                for j in range(d_in):
                    if not a[i, j] > 0.0:  # ReLU's derivative (a is the layer's post-ReLU input), 0 at NaN
                        g_in[i, j] = 0.0
            g = g_in


@_compiled
def _surrogate(logp, old_logp, adv, m, clip, stats):
    """dL/d(log π) of the clipped surrogate for one sample; adds its loss, KL and clip terms to stats."""
    logratio = logp - old_logp
    ratio = math.exp(logratio)
    clipped = min(max(ratio, 1.0 - clip), 1.0 + clip)
    loss1, loss2 = -adv * ratio, -adv * clipped
    stats[0] += max(loss1, loss2)
    stats[3] += (ratio - 1.0) - logratio
    if abs(ratio - 1.0) > clip:
        stats[4] += 1.0
    # torch.maximum sends the gradient to the larger term; the clipped one has none outside [1 - ε, 1 + ε]
    inside = 1.0 - clip <= ratio <= 1.0 + clip
    return -adv * ratio / m if (inside or loss1 > loss2) else 0.0


@_compiled
def _categorical_head(out, g_out, idx, actions, old_logp, adv, clip, beta, scratch, stats):
    """Softmax with the 1e-8 floor: fills dL/d(logits) `g_out` [mb, K]; `scratch` is float64 [2, K].

    log q = max(log p, log 1e-8), with log p = z − log Σ exp z (z = logits − max): one logarithm per sample
    instead of one per action (the same value as log(softmax) to a few float64 ulps)."""
    mb, k = out.shape
    p, g = scratch[0], scratch[1]
    log_floor = math.log(PROB_FLOOR)
    for i in range(mb):
        s = idx[i]
        top = out[i, 0]
        for j in range(1, k):
            top = max(top, out[i, j])
        total = 0.0
        for j in range(k):
            p[j] = math.exp(out[i, j] - top)
            total += p[j]
        log_total = math.log(total)
        entropy = 0.0
        for j in range(k):
            p[j] /= total
            log_q = max(out[i, j] - top - log_total, log_floor)
            entropy -= max(p[j], PROB_FLOOR) * log_q
            g[j] = (beta / mb) * (log_q + 1.0)  # d(−β·mean H)/dq
        stats[2] += entropy
        a = actions[s]
        log_qa = max(out[i, a] - top - log_total, log_floor)
        g[a] += _surrogate(log_qa, old_logp[s], adv[s], mb, clip, stats) / max(p[a], PROB_FLOOR)  # d log q/dq = 1/q
        dot = 0.0
        for j in range(k):  # no gradient below the floor (the clamp); then back through the softmax
            if p[j] < PROB_FLOOR:
                g[j] = 0.0
            dot += g[j] * p[j]
        for j in range(k):
            g_out[i, j] = p[j] * (g[j] - dot)


@_compiled
def _gaussian_head(out, g_out, idx, actions, old_logp, adv, clip, beta, log_std, g_log_std, stats):
    """N(mean, exp(clip(log_std))): fills dL/d(mean) `g_out` [mb, D] and dL/d(log_std) `g_log_std` [D]."""
    mb, d = out.shape
    ent = 0.0
    for c in range(d):
        ent += 0.5 + _HALF_LOG_2PI + min(max(log_std[c], PPO_LOG_STD_MIN), PPO_LOG_STD_MAX)
        g_log_std[c] = 0.0
    for i in range(mb):
        s = idx[i]
        logp = 0.0
        for c in range(d):
            ls = min(max(log_std[c], PPO_LOG_STD_MIN), PPO_LOG_STD_MAX)
            z = (actions[s, c] - out[i, c]) / math.exp(ls)
            logp += -0.5 * z * z - ls - _HALF_LOG_2PI
        stats[2] += ent
        g_logp = _surrogate(logp, old_logp[s], adv[s], mb, clip, stats)
        for c in range(d):
            std = math.exp(min(max(log_std[c], PPO_LOG_STD_MIN), PPO_LOG_STD_MAX))
            z = (actions[s, c] - out[i, c]) / std
            g_out[i, c] = g_logp * z / std
            g_log_std[c] += g_logp * (z * z - 1.0)
    for c in range(d):
        inside = PPO_LOG_STD_MIN <= log_std[c] <= PPO_LOG_STD_MAX
        g_log_std[c] = (g_log_std[c] - beta) if inside else 0.0


@_compiled
def _value_head(out, g_out, idx, returns, huber):
    """Huber (δ = 1) or squared error of V [mb, 1]: fills dL/dV, returns the loss."""
    mb = out.shape[0]
    loss = 0.0
    for i in range(mb):
        d = float(out[i, 0]) - returns[idx[i]]
        if huber:
            a = abs(d)
            loss += 0.5 * d * d if a < 1.0 else a - 0.5
            g_out[i, 0] = min(max(d, -1.0), 1.0) / mb
        else:
            loss += d * d
            g_out[i, 0] = 2.0 * d / mb
    return loss / mb


@_compiled
def _adam(flat, grads, m, v, t, lr, beta1, beta2, eps):
    """torch.optim.Adam's step t (no weight decay, no amsgrad), in place, in float32 as torch computes it.

    One difference: a moment that falls below float32's smallest normal number (1.2e-38) is stored as 0.
    The first moment of a weight whose gradient is 0 (a dead ReLU unit) shrinks by 0.9 a step and is
    subnormal after ~800 steps; arithmetic on subnormals is ~100x slower, and with 9 % of them (measured
    after 6 iterations) Adam took 19 µs instead of 6. Such a moment moves its weight by < 1e-33."""
    step_size = np.float32(lr / (1.0 - beta1 ** t))
    bc2_sqrt = np.float32(math.sqrt(1.0 - beta2 ** t))
    b1, b2, c1, c2 = np.float32(beta1), np.float32(beta2), np.float32(1.0 - beta1), np.float32(1.0 - beta2)
    e, zero = np.float32(eps), np.float32(0.0)
    for j in range(flat.shape[0]):
        g = grads[j]
        mj = b1 * m[j] + c1 * g
        vj = b2 * v[j] + c2 * g * g
        mj = zero if abs(mj) < _SMALLEST_NORMAL else mj
        vj = zero if vj < _SMALLEST_NORMAL else vj
        m[j] = mj
        v[j] = vj
        flat[j] -= step_size * mj / (np.sqrt(vj) / bc2_sqrt + e)


@_compiled
def _offsets(layers, mb):
    """Start of each activation [mb, width] in one buffer (input, each layer's output), and its end."""
    n = layers.shape[0]
    offsets = np.zeros(n + 2, dtype=np.int64)
    offsets[1] = layers[0, 2] * mb
    for k in range(n):
        offsets[k + 2] = offsets[k + 1] + layers[k, 3] * mb
    return offsets


@_compiled
def ppo_steps(x, actions_i, actions_f, old_logp, adv, returns, batches, flat, grads, m, v, t0,
              p_layers, v_layers, log_std_offset, discrete, clip, beta, huber, lr, beta1, beta2, eps, history):
    """One Adam step per row of `batches` [S, mb] (sample indices); returns the number of steps taken.

    Stops before a step whose loss is not finite (that step's row of `history` is left as it was).
    `actions_i` [N] for a categorical policy, `actions_f` [N, D] for a Gaussian one (the other is unused).
    history [S, 5] gets each step's pg_loss, v_loss, entropy, approx_kl and clipfrac.
    """
    steps, mb = batches.shape
    x_dim = x.shape[1]
    p_offsets = _offsets(p_layers, mb)
    v_offsets = _offsets(v_layers, mb)
    p_acts = np.empty(p_offsets[-1], dtype=np.float32)
    v_acts = np.empty(v_offsets[-1], dtype=np.float32)
    widest = max(p_layers[:, 2].max(), v_layers[:, 2].max())
    work = np.empty(2 * mb * widest, dtype=np.float32)
    k_out = p_layers[-1, 3]
    g_pol = np.empty((mb, k_out), dtype=np.float32)
    g_val = np.empty((mb, 1), dtype=np.float32)
    scratch = np.empty((2, k_out), dtype=np.float64)
    g_ls = np.empty(k_out, dtype=np.float64)
    stats = np.zeros(HISTORY_COLUMNS, dtype=np.float64)
    n_p = p_offsets.shape[0] - 2
    n_v = v_offsets.shape[0] - 2
    for step in range(steps):
        idx = batches[step]
        xp = _view(p_acts, 0, mb, x_dim)
        xv = _view(v_acts, 0, mb, x_dim)
        for i in range(mb):
            for j in range(x_dim):
                xp[i, j] = x[idx[i], j]
                xv[i, j] = x[idx[i], j]
        _forward(flat, p_layers, p_acts, p_offsets, mb)
        _forward(flat, v_layers, v_acts, v_offsets, mb)
        stats[:] = 0.0
        pol_out = _view(p_acts, p_offsets[n_p], mb, k_out)
        val_out = _view(v_acts, v_offsets[n_v], mb, 1)
        if discrete:
            _categorical_head(pol_out, g_pol, idx, actions_i, old_logp, adv, clip, beta, scratch, stats)
        else:
            log_std = flat[log_std_offset:log_std_offset + k_out]
            _gaussian_head(pol_out, g_pol, idx, actions_f, old_logp, adv, clip, beta, log_std, g_ls, stats)
        v_loss = _value_head(val_out, g_val, idx, returns, huber)
        pg_loss, entropy = stats[0] / mb, stats[2] / mb
        if not math.isfinite(pg_loss + v_loss - beta * entropy):
            return step
        history[step, 0], history[step, 1], history[step, 2] = pg_loss, v_loss, entropy
        history[step, 3], history[step, 4] = stats[3] / mb, stats[4] / mb
        _backward(flat, grads, p_layers, p_acts, p_offsets, g_pol, work, mb)
        if not discrete:
            for c in range(k_out):
                grads[log_std_offset + c] = g_ls[c]
        _backward(flat, grads, v_layers, v_acts, v_offsets, g_val, work, mb)
        _adam(flat, grads, m, v, t0 + step + 1, lr, beta1, beta2, eps)
    return steps


_WARM = False


def warm_up() -> None:
    """Compile `ppo_steps` (or load it from numba's cache) now, on a one-step toy problem, so the first
    training update does not pay for it. Every argument has the types the updater passes."""
    global _WARM
    if _WARM:
        return
    x = np.ones((2, 1), dtype=np.float32)
    flat = np.full(6, 0.1, dtype=np.float32)  # policy W [2, 1], b [2]; value W [1, 1], b [1]
    p_layers = np.array([[0, 2, 1, 2]], dtype=np.int64)
    v_layers = np.array([[4, 5, 1, 1]], dtype=np.int64)
    ones = np.ones(2, dtype=np.float32)
    ppo_steps(x, np.zeros(2, dtype=np.int64), np.zeros((1, 1), dtype=np.float32), ones, ones, ones,
              np.array([[0, 1]], dtype=np.int64), flat, np.zeros_like(flat), np.zeros_like(flat), np.zeros_like(flat),
              0, p_layers, v_layers, 0, True, 0.2, 0.01, True, 1e-3, 0.9, 0.999, 1e-5, np.zeros((1, HISTORY_COLUMNS)))
    _WARM = True

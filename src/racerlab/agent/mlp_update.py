"""PPO's minibatch update for small vector networks, in NumPy with the gradients written out by hand.

Why: a `features` or lidar network is a chain of a few dense layers; a gradient step on 64 samples is a
few million FLOPs, done in ~0.1 ms by BLAS, while PyTorch's eager autograd and Adam spend ~1 ms per
step in dispatch and bookkeeping. AWS runs 10 epochs of N/64 minibatches per iteration, so that
overhead alone made the update take several times longer than collecting the episodes.

What it computes is exactly `PPO.update`'s loss and Adam step (float32; the tests compare both
implementations step by step): the clipped surrogate, Huber (δ = 1) or squared value loss, the
entropy bonus, the probability floor of `Categorical` and the log-std clip of `DiagGaussian`, Adam
with torch's bias correction. The weights live in the torch modules; each update copies them and the
Adam moments in, runs all minibatches, and copies them back, so checkpoints, `act` and a later torch
update see the same state.

`MLPUpdater` runs the steps in one numba-compiled function (`mlp_kernel`, ~8x faster on 64-wide layers)
unless asked for the NumPy functions here, which it was written from and which stay as the reference.
`VectorChain.of(net)` returns None for a network it does not cover (images, several inputs, SAC).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from threadpoolctl import ThreadpoolController
from torch import nn

from racerlab.agent import mlp_kernel
from racerlab.agent.distributions import PPO_LOG_STD_MAX, PPO_LOG_STD_MIN, PROB_FLOOR

_HALF_LOG_2PI = np.float32(0.5 * np.log(2.0 * np.pi))


@dataclass
class VectorChain:
    """A network that is Linear, ReLU, ..., Linear (the head) on one vector input, as NumPy views."""

    linears: list[nn.Linear]

    @classmethod
    def of(cls, net: nn.Module) -> VectorChain | None:
        body = net.body
        if len(body.keys) != 1 or not hasattr(body.embedders[body.keys[0]], "net"):
            return None
        layers = [*body.embedders[body.keys[0]].net, *body.middleware]
        linears = layers[0::2]
        ok = all(isinstance(m, nn.Linear) for m in linears) and all(isinstance(m, nn.ReLU) for m in layers[1::2])
        if not ok or len(layers) % 2:
            return None
        return cls([*linears, net.head])

    def parameters(self) -> list[nn.Parameter]:
        return [p for lin in self.linears for p in (lin.weight, lin.bias)]

    def forward(self, w: list[np.ndarray], x: np.ndarray) -> list[np.ndarray]:
        """Activations [input, hidden..., output]; `w` holds (W, b) pairs as flat NumPy arrays in order."""
        acts = [x]
        last = len(self.linears) - 1
        for k in range(len(self.linears)):
            h = acts[-1] @ w[2 * k].T
            h += w[2 * k + 1]
            if k < last:
                np.maximum(h, 0.0, out=h)
            acts.append(h)
        return acts

    def backward(self, w: list[np.ndarray], acts: list[np.ndarray], grad_out: np.ndarray,
                 grads: list[np.ndarray]) -> None:
        """Write dL/dW, dL/db into `grads` (same order as `w`) from dL/d(output)."""
        g = grad_out
        for k in range(len(self.linears) - 1, -1, -1):
            np.matmul(g.T, acts[k], out=grads[2 * k])
            np.sum(g, axis=0, out=grads[2 * k + 1])
            if k:
                g = g @ w[2 * k]
                g *= acts[k] > 0.0


class Adam:
    """torch.optim.Adam's update (no weight decay, no amsgrad) on flat float32 arrays."""

    def __init__(self, lr: float, betas: tuple[float, float], eps: float):
        self.lr, self.betas, self.eps = lr, betas, eps

    def step(self, p: np.ndarray, g: np.ndarray, m: np.ndarray, v: np.ndarray, t: int) -> None:
        """One step on flat arrays, in place: p the weights, g the gradients, m and v the moments."""
        b1, b2 = self.betas
        step_size = np.float32(self.lr / (1.0 - b1 ** t))
        m *= b1
        m += (1.0 - b1) * g
        v *= b2
        v += (1.0 - b2) * g * g
        denom = np.sqrt(v)
        denom /= np.sqrt(1.0 - b2 ** t)
        denom += self.eps
        p -= step_size * m / denom


def policy_head_grad(out, actions, old_log_probs, advantages, log_std, *, discrete: bool, clip: float,
                     beta: float) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """(dL/d(policy output) [M, K], dL/d(log_std) [D] or None, [pg_loss, entropy, approx_kl, clipfrac])."""
    m = out.shape[0]
    if discrete:
        z = out - out.max(axis=1, keepdims=True)
        e = np.exp(z)
        p = e / e.sum(axis=1, keepdims=True)
        q = np.maximum(p, PROB_FLOOR)
        logq = np.log(q)
        rows = np.arange(m)
        logp = logq[rows, actions]
        entropy = -(q * logq).sum(axis=1)
    else:
        ls_clipped = np.clip(log_std, PPO_LOG_STD_MIN, PPO_LOG_STD_MAX)
        std = np.exp(ls_clipped)
        zz = (actions - out) / std
        logp = (-0.5 * zz * zz - ls_clipped - _HALF_LOG_2PI).sum(axis=1)
        entropy = np.full(m, (0.5 + _HALF_LOG_2PI + ls_clipped).sum(), dtype=np.float32)
    logratio = logp - old_log_probs
    ratio = np.exp(logratio)
    clipped = np.clip(ratio, 1.0 - clip, 1.0 + clip)
    loss1, loss2 = -advantages * ratio, -advantages * clipped
    # torch.maximum sends the gradient to the larger term (half to each on a tie, the same sum here);
    # the clipped term has no gradient outside [1 - ε, 1 + ε].
    inside = (ratio >= 1.0 - clip) & (ratio <= 1.0 + clip)
    g_logp = np.where(inside | (loss1 > loss2), -advantages * ratio, 0.0).astype(np.float32) / m
    stats = np.array([np.maximum(loss1, loss2).mean(), entropy.mean(), ((ratio - 1.0) - logratio).mean(),
                      (np.abs(ratio - 1.0) > clip).mean()], dtype=np.float64)
    if discrete:
        # d(logp)/dq is 1/q at the action; d(-β·mean H)/dq = β(log q + 1)/M; the floor blocks p < 1e-8
        g_q = np.zeros_like(q)
        g_q[rows, actions] = g_logp / q[rows, actions]
        g_q += (beta / m) * (logq + 1.0)
        g_q *= p >= PROB_FLOOR
        g_out = p * (g_q - (g_q * p).sum(axis=1, keepdims=True))
        return g_out.astype(np.float32), None, stats
    g_out = (g_logp[:, None] * zz / std).astype(np.float32)
    inside_ls = (log_std >= PPO_LOG_STD_MIN) & (log_std <= PPO_LOG_STD_MAX)
    g_ls = ((g_logp[:, None] * (zz * zz - 1.0)).sum(axis=0) - beta) * inside_ls
    return g_out, g_ls.astype(np.float32), stats


def value_head_grad(values, returns, loss_type: str) -> tuple[np.ndarray, float]:
    """(dL/dV [M, 1], value loss) for Huber with δ = 1 or the mean squared error."""
    m = values.shape[0]
    d = values - returns
    if loss_type == "huber":
        a = np.abs(d)
        loss = np.where(a < 1.0, 0.5 * d * d, a - 0.5).mean()
        g = np.clip(d, -1.0, 1.0) / m
    else:
        loss = (d * d).mean()
        g = 2.0 * d / m
    return g.astype(np.float32)[:, None], float(loss)


class MLPUpdater:
    """Runs PPO minibatch steps on a `VectorChain` policy and value network without autograd.

    `engine` "numba" (the default) runs the steps in one compiled function (`mlp_kernel.ppo_steps`);
    "numpy" runs them with the NumPy functions above, one array operation at a time (the reference the
    compiled path was written from; ~5x slower on 64-wide layers).
    """

    ENGINES = ("numba", "numpy")

    def __init__(self, policy_net, value_net, optimizer: torch.optim.Adam, *, discrete: bool, engine: str = "numba"):
        if engine not in self.ENGINES:
            raise ValueError(f"MLPUpdater engine must be one of {self.ENGINES}, got {engine!r}")
        self.policy = VectorChain.of(policy_net)
        self.value = VectorChain.of(value_net)
        self.policy_net, self.discrete, self.optimizer, self.engine = policy_net, discrete, optimizer, engine
        self.torch_params = [*self.policy.parameters(), *([] if discrete else [policy_net.log_std]),
                             *self.value.parameters()]
        self._np = len(self.policy.linears) * 2
        sizes = np.cumsum([0, *(p.numel() for p in self.torch_params)])
        self._p_layers = _layer_table(self.policy.linears, sizes, 0)
        self._log_std_offset = int(sizes[self._np])
        self._v_layers = _layer_table(self.value.linears, sizes, len(self.torch_params) - 2 * len(self.value.linears))
        self._weights: list[np.ndarray] | None = None
        if engine == "numba":
            mlp_kernel.warm_up()

    def greedy(self, x: np.ndarray) -> np.ndarray:
        """The policy's greedy actions for observations [B, F]: the argmax of the logits (the most probable
        action; the 1e-8 floor never touches the largest probability) or the Gaussian's mean [B, D]."""
        if self._weights is None:  # views of the torch parameters, which every update changes in place
            self._weights = [p.detach().numpy() for p in self.policy.parameters()]
        # no thread limit: OpenBLAS runs products this small on one thread anyway, and the limit costs ~40 µs
        out = self.policy.forward(self._weights, np.asarray(x, dtype=np.float32).reshape(len(x), -1))[-1]
        return out.argmax(axis=1) if self.discrete else out

    @staticmethod
    def covers(policy_net, value_net, device: torch.device) -> bool:
        return device.type == "cpu" and VectorChain.of(policy_net) is not None and \
            VectorChain.of(value_net) is not None

    def _load(self):
        """Weights and Adam moments as one flat float32 buffer each (one Adam pass over all of them),
        with a view per parameter; the step count."""
        shapes = [tuple(p.shape) for p in self.torch_params]
        flat = np.concatenate([p.detach().cpu().numpy().ravel() for p in self.torch_params]).astype(np.float32)
        m, v, t = np.zeros_like(flat), np.zeros_like(flat), 0
        states = [self.optimizer.state.get(p, {}) for p in self.torch_params]
        if all("exp_avg" in st for st in states):
            m[:] = np.concatenate([st["exp_avg"].cpu().numpy().ravel() for st in states])
            v[:] = np.concatenate([st["exp_avg_sq"].cpu().numpy().ravel() for st in states])
            t = int(states[0]["step"])
        return shapes, flat, m, v, t

    @staticmethod
    def _views(flat: np.ndarray, shapes) -> list[np.ndarray]:
        out, at = [], 0
        for shape in shapes:
            n = int(np.prod(shape))
            out.append(flat[at:at + n].reshape(shape))
            at += n
        return out

    def _store(self, shapes, flat, m, v, t):
        with torch.no_grad():
            views = zip(self._views(flat, shapes), self._views(m, shapes), self._views(v, shapes), strict=True)
            for p, (arr, mk, vk) in zip(self.torch_params, views, strict=True):
                p.copy_(torch.from_numpy(arr))
                self.optimizer.state[p] = {"step": torch.tensor(float(t)), "exp_avg": torch.from_numpy(mk.copy()),
                                           "exp_avg_sq": torch.from_numpy(vk.copy())}

    def run(self, x, actions, old_log_probs, advantages, returns, blocks, *, clip: float, beta: float,
            loss_type: str) -> tuple[list[np.ndarray], bool]:
        """Adam steps over `blocks`, each an int64 array [S, mb] of minibatch indices, in order; returns
        (per-step losses, nonfinite).

        One BLAS thread: these products are too small to share, and a second thread that waits for
        work spins, which on a busy machine made a step 6x slower (measured at load 12 on 2 cores).
        """
        run = self._run_numba if self.engine == "numba" else self._run_numpy
        with _one_blas_thread():
            return run(x, actions, old_log_probs, advantages, returns, blocks, clip, beta, loss_type)

    def _run_numba(self, x, actions, old_log_probs, advantages, returns, blocks, clip, beta, loss_type):
        group = self.optimizer.param_groups[0]
        b1, b2 = group["betas"]
        shapes, flat, m, v, t = self._load()
        grads = np.zeros_like(flat)
        actions_i = actions if self.discrete else np.zeros(1, dtype=np.int64)
        actions_f = np.zeros((1, 1), dtype=np.float32) if self.discrete else actions
        history, nonfinite = [], False
        for block in blocks:
            rows = np.zeros((len(block), mlp_kernel.HISTORY_COLUMNS))
            done = mlp_kernel.ppo_steps(x, actions_i, actions_f, old_log_probs, advantages, returns,
                                        np.ascontiguousarray(block, dtype=np.int64), flat, grads, m, v, t,
                                        self._p_layers, self._v_layers, self._log_std_offset, self.discrete,
                                        float(clip), float(beta), loss_type == "huber", float(group["lr"]),
                                        float(b1), float(b2), float(group["eps"]), rows)
            t += done
            history.extend(rows[:done])
            if done < len(block):
                nonfinite = True
                break
        self._store(shapes, flat, m, v, t)
        return history, nonfinite

    def _run_numpy(self, x, actions, old_log_probs, advantages, returns, blocks, clip, beta, loss_type):
        group = self.optimizer.param_groups[0]
        adam = Adam(group["lr"], group["betas"], group["eps"])
        shapes, flat, m, v, t = self._load()
        flat_grads = np.empty_like(flat)
        params, grads = self._views(flat, shapes), self._views(flat_grads, shapes)
        pw = params[:self._np]
        vw = params[len(params) - len(self.value.linears) * 2:]
        log_std = None if self.discrete else params[self._np]
        history, nonfinite = [], False
        for idx in (row for block in blocks for row in block):
            xb = x[idx]
            pa = self.policy.forward(pw, xb)
            va = self.value.forward(vw, xb)
            g_out, g_ls, stats = policy_head_grad(pa[-1], actions[idx], old_log_probs[idx], advantages[idx], log_std,
                                                  discrete=self.discrete, clip=clip, beta=beta)
            g_v, v_loss = value_head_grad(va[-1][:, 0], returns[idx], loss_type)
            loss = stats[0] + v_loss - beta * stats[1]
            if not np.isfinite(loss):
                nonfinite = True
                break
            self.policy.backward(pw, pa, g_out, grads[:self._np])
            if g_ls is not None:
                grads[self._np][...] = g_ls
            self.value.backward(vw, va, g_v, grads[len(grads) - len(vw):])
            t += 1
            adam.step(flat, flat_grads, m, v, t)
            history.append(np.array([stats[0], v_loss, stats[1], stats[2], stats[3]]))
        self._store(shapes, flat, m, v, t)
        return history, nonfinite


def _layer_table(linears: list[nn.Linear], sizes: np.ndarray, first: int) -> np.ndarray:
    """(weight offset, bias offset, inputs, outputs) of each layer in the flat buffer; `first` is the index of the
    chain's first weight among the updater's parameters, `sizes` their cumulative sizes."""
    rows = [(sizes[first + 2 * k], sizes[first + 2 * k + 1], lin.in_features, lin.out_features)
            for k, lin in enumerate(linears)]
    return np.array(rows, dtype=np.int64)


_BLAS = None


def _one_blas_thread():
    """threadpoolctl's limit to one BLAS thread (NumPy's and SciPy's, which numba's np.dot calls), with the
    libraries looked up once per process."""
    global _BLAS
    if _BLAS is None:
        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api="blas")

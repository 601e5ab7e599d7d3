"""Hill-climbing on contexts: isModelImprovement (Algorithm 1) and Update Context (Algorithm 3).

Both work on :class:`~.dbn.ModelStats`, so they can be tested with hand-made numbers.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from .dbn import ModelStats
from .params import Params


def _brel_gain(new: float | None, old: float | None) -> float:
    """brel(r') − brel(r) with ⊥ below every value (Appendix B.1)."""
    if new is None:
        return float("-inf")
    if old is None:
        return float("inf")
    return new - old


def is_model_improvement(r: ModelStats, r2: ModelStats, params: Params) -> bool:
    """Algorithm 1: is r' (``r2``) a sufficient improvement over r? (§4.3.1)

    The ``entropy_only`` ablation (§7.11) always uses the entropy branch.
    """
    delta = r2.n_context - r.n_context
    theta = params.theta_pen
    if params.ablations.entropy_only:
        if r.n_context <= r2.n_context:
            return r.entropy - r2.entropy > (1 + delta) * theta
        return not is_model_improvement(r2, r, params)
    if r.reliable:
        if not r2.reliable:
            return False
        if r.n_context <= r2.n_context:
            return r.entropy - r2.entropy > (1 + delta) * theta
        return not is_model_improvement(r2, r, params)
    if r.n_context <= r2.n_context:
        return _brel_gain(r2.brel, r.brel) > (1 + delta) * theta
    return not is_model_improvement(r2, r, params)


Chooser = Callable[[tuple[int, ...], list[int], bool], tuple[int, ModelStats]]


def update_context(current: tuple[int, ...], candidates: Sequence[int],
                   evaluate: Callable[[tuple[int, ...]], ModelStats],
                   params: Params, choose: Chooser | None = None) -> tuple[int, ...] | None:
    """Algorithm 3 (Appendix D.1): rebuild a context from ∅ by hill-climbing.

    ``evaluate(context)`` gives the DBN's statistics under a context on the stored activations.
    Returns the new context if it improves on ``current`` (isModelImprovement), else None.
    At most ``params.max_context_vars`` variables are added (§4.2.1 footnote 1). Ties are broken
    by the lower variable index, so the result is deterministic.

    ``choose(ctx, options, by_entropy)``, if given, returns the option and statistics the
    default would pick for one round (the lowest entropy if ``by_entropy``, else the highest
    brel, ties to the lower index) — a faster way to score all options at once.
    """
    # evaluate is pure: each context is scored once (the final comparison with ``current``
    # often meets a context the climb already scored).
    scores: dict[tuple[int, ...], ModelStats] = {}

    def score(c: tuple[int, ...]) -> ModelStats:
        r = scores.get(c)
        if r is None:
            r = scores[c] = evaluate(c)
        return r

    ctx: tuple[int, ...] = ()
    r1 = score(ctx)
    while len(ctx) < params.max_context_vars:
        options = [v for v in candidates if v not in ctx]
        if not options:
            break
        by_entropy = r1.reliable or params.ablations.entropy_only
        if choose is not None:
            v, r2 = choose(ctx, options, by_entropy)
            scores.setdefault(tuple(sorted((*ctx, v))), r2)
        else:
            scored = [(v, score(tuple(sorted((*ctx, v))))) for v in options]
            if by_entropy:
                v, r2 = min(scored, key=lambda p: (p[1].entropy, p[0]))
            else:
                v, r2 = max(scored,
                            key=lambda p: (-1.0 if p[1].brel is None else p[1].brel, -p[0]))
        if not is_model_improvement(r1, r2, params):
            break
        ctx = tuple(sorted((*ctx, v)))
        r1 = r2
    if tuple(sorted(current)) != ctx:
        # r: the DBN under its current context (evaluated only when needed).
        r = score(tuple(current))
        if is_model_improvement(r, r1, params):
            return ctx
    return None

"""Every number of QLAP in one typed, documented place.

Defaults are the reference's values (Mugan's dissertation, Appendix G and the numbers quoted in
chapters 4–6 and Appendices B–E). Nothing else in the project hard-codes a threshold. The
ablation switches of §7.11 are fields of :class:`Ablations`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Ablations:
    """The experimental conditions of §7.11.1 (all ``False`` is normal QLAP)."""

    no_iac: bool = False
    """Choose actions to practice uniformly at random instead of by IAC (§6.1.1)."""
    no_dyna: bool = False
    """Skip the Dyna sweep when a plan's statistics change (§5.2.2)."""
    no_sarsa: bool = False
    """Skip the Sarsa(λ) update when a sub-action terminates (§5.2.2)."""
    entropy_only: bool = False
    """Hill-climb on entropy only, never on best reliability (§4.3.1)."""
    no_targeted: bool = False
    """Never lower thresholds for sufficiently rare events (§6.3)."""
    all_targeted: bool = False
    """Use the targeted thresholds for every event (§6.3)."""
    nrc: bool = False
    """No restriction that a new DBN's antecedent be predicted by a deterministic DBN (§6.2.3)."""
    nrp: bool = False
    """No restriction that a DBN's antecedent be achievable by a reliable plan (§6.2.2)."""


READINGS: dict[str, tuple[str, ...]] = {
    "iac_progress": ("cumulative", "windowed"),
    "plan_replace": ("eligible", "lowest"),
    "plan_reliable": ("o", "dbn"),
    "achieved_call": ("fail", "support"),
    "iac_records": ("all", "practice"),
}
"""The readings a switch of :class:`Params` may name (the first is the default; the others
were measured and rejected, docs/decisions.md)."""


@dataclass(frozen=True)
class Params:
    """QLAP's parameters; the docstring under each field names its source section."""

    # --- thresholds (Appendix G, Table G.1) ---------------------------------------------------
    theta_sr: float = 0.75
    """θ_SR: a DBN/plan/action is sufficiently reliable when brel (rel(a)) exceeds it (§4.2.2)."""
    theta_pen: float = 0.05
    """θ_pen: needed improvement for a contingency and in isModelImprovement (§4.1.2, Alg. 1)."""
    theta_ig: float = 0.30
    """θ_IG: required information gain of a DBN landmark cut (§4.4.1, eq. 4.17)."""
    theta_e: float = 0.30
    """θ_E: required probability difference for an event landmark (§4.4.2, eq. 4.18)."""

    # --- probabilities (Appendix B) ----------------------------------------------------------
    prior: float = 1.0
    """α = β prior for success probabilities (eq. B.1)."""
    prior_action_reliable: float = 2.0
    """α = β when deciding whether an action is sufficiently reliable (App. B, §6.2.1)."""
    prior_plan_replace: float = 0.0
    """α = β when deciding which plan to replace (App. B, §6.2.2)."""
    beta_confidence: float = 0.8
    """Probability mass the beta test needs to call p_s above/below a threshold (eq. B.2)."""
    brel_min_successes: int = 5
    """Successes needed in a context value before it counts for brel; else brel = ⊥ (B.1)."""
    min_data_points: int = 30
    """The 30-data-point rule for new DBNs and both landmark searches (App. B.2)."""

    # --- qualitative representation (ch. 3) --------------------------------------------------
    derivative_zero_band: float = 0.05
    """Half-width of the range of the landmark 0 on direction-of-change variables: [−0.05, 0.05]
    (Table 8.1). The derivative is per second, (ṽ(t) − ṽ(t−1)) / ``step_seconds``, the
    reference's scale (Tables 8.7–8.10: Δh_x ≈ 0.46 per step is ḣ_x ≈ 9.2)."""
    step_seconds: float = 1.0
    """Physical duration of one agent step in seconds (a world property, ``World.step_seconds``,
    set by ``params_for_world``); derivatives are divided by it."""
    motor_zero_band: float = 0.0
    """Half-width of the range of the initial motor landmark 0 (Table 3.1); 0 means exactly 0.
    A motor whose range does not contain 0 in its interior gets its initial landmark at the
    middle of its range instead (docs/decisions.md)."""
    motor_resolution: float = 0.01
    """A motor's resolution is this fraction of its range: no learned landmark is narrower, and
    no two landmarks of the motor are closer (docs/decisions.md; Table 8.1 has none closer)."""
    change_epsilon: float = 0.001
    """|ṽ(t) − ṽ(t−1)| above which a change counts for event-landmark bins (§4.4.2)."""
    cut_min_gap: float = 0.001
    """Minimum ub − lb between adjacent sorted values for a Fayyad–Irani cutpoint (§4.4.1)."""

    # --- contingencies and DBNs (§4.1–4.3, App. C) -------------------------------------------
    k_initial: int = 1
    """Window k before Appendix C's estimate exists. §7.10.1 uses a fixed k of 6 for pong."""
    k_fixed: int | None = None
    """If set, k is fixed (a world option, e.g. pong's k = 6, §7.10.1) instead of learned."""
    max_context_vars: int = 2
    """At most this many context variables per DBN (§4.2.1 footnote 1)."""
    landmark_once: bool = True
    """App. D.2 item 1: in one execution of Algorithm 4 a DBN already improved upon by another
    new landmark (one adopted for a DBN of higher weighted gain) gets none of its own
    (docs/decisions.md 113); False: every DBN may add its best."""
    stored_activations: int = 200
    """Activations kept per DBN for context and landmark learning (§4.4.1)."""
    dbn_max_age: int = 100_000
    """A DBN not deterministic nor a plan after this many steps is deleted (§6.2.3)."""

    # --- batch schedule (Algorithm 2) --------------------------------------------------------
    dbn_period: int = 2000
    """Learn DBNs, update contexts, delete DBNs, convert to plans every this many steps (Alg. 2)."""
    landmark_period: int = 4000
    """Learn landmarks on events and on DBNs every this many steps (Alg. 2 lines 10–13)."""
    batch_lag: int = 0
    """L: a batch from data up to step t is applied at t + L (docs/architecture.md §2;
    0 = Algorithm 2)."""
    event_history: int = 20_000
    """Bound on the real-valued history kept for event landmarks (§8.3; bounded memory)."""

    # --- targeted learning (§6.3) ------------------------------------------------------------
    rare_event_fraction: float = 0.05
    """An event satisfied less often than this is sufficiently rare (§6.3)."""
    theta_pen_targeted: float = 0.02
    """θ_pen for contingencies whose consequent is targeted (§6.3)."""
    theta_sr_targeted: float = 0.25
    """θ_SR for converting a DBN on a targeted event to a plan (§6.3)."""
    nrp_targeted: bool = False
    """§6.2.2 criterion 1 for a DBN whose consequent is targeted: a plan of its antecedent
    with brel(o) > theta_sr_targeted now counts as sufficiently reliable (docs/decisions.md
    75, 89; measured and rejected); off: θ_SR = 0.75 as for any DBN."""

    # --- planning (§5.2–5.4) -----------------------------------------------------------------
    step_reward: float = -2.0
    """Reward of each MDP action (eq. 5.5)."""
    goal_reward: float = 10.0
    """Reward for reaching the goal Y = y (eq. 5.5, 5.8)."""
    gamma: float = 0.9
    """Discount γ for value iteration and Sarsa (§5.2.2)."""
    sarsa_lambda: float = 0.9
    """λ of the replacing traces (eq. 5.9)."""
    sarsa_alpha: float = 0.2
    """Sarsa step size (not stated in §5.2.2; the Dyna α and App. H's α are 0.2)."""
    sarsa_time_cost: float = 0.01
    """r' = R(s) − 0.01·t, t the option's steps (§5.2.2)."""
    dyna_alpha: float = 0.2
    """Dyna learning rate (eq. 5.10)."""
    value_iteration_tol: float = 1e-6
    """Stopping tolerance of value iteration (eq. 5.6)."""
    value_iteration_max_sweeps: int = 500
    """Cap on value-iteration sweeps."""
    option_max_steps: int = 300
    """An option is terminated after this many steps (§5.2.3)."""
    option_max_calls: int = 5
    """An option is terminated after this many action calls (§5.2.3)."""
    stuck_steps: int = 10
    """An option is stuck if no self or state variable changed in this many steps (§5.2.3)."""

    # --- exploration (§6.1, App. E) ----------------------------------------------------------
    babble_steps: int = 20_000
    """Initial motor-babbling period (§6.1)."""
    babble_max_hold: int = 40
    """Each motor holds a random value for a random 0..this many steps (App. E)."""
    babble_probability: float = 0.1
    """After babbling, probability of a babbling command instead of IAC (§6.1.1)."""
    iac_window: int = 25
    """θ = τ: IAC compares mean rel(a) over the last 25 calls with the 25 before (eq. 6.1)."""
    iac_min_weight: float = 0.001
    """w_a = max(0.001, rel_new − rel_old) (eq. 6.1)."""
    iac_progress: str = "cumulative"
    """What eq. 6.1 averages over its windows of θ calls: ``"cumulative"``, rel(a) over all
    calls as recorded at each termination; ``"windowed"``, each call's outcome (1 success, 0
    failure), so rel_new and rel_old are the success rates of the last θ calls and the θ
    before (docs/decisions.md 78)."""
    iac_records: str = "all"
    """Which terminations eq. 6.1 records and counts towards its 2θ calls: ``"all"``, every
    termination of the action, as a sub-action of a plan too; ``"practice"``, only those of
    calls made to practise it (docs/decisions.md 79)."""
    achieved_call: str = "fail"
    """A direction-of-change action called by a plan while its value already holds:
    ``"fail"``, it fails at its call (docs/decisions.md 70); ``"support"``, §5.5 footnote 5
    ("its plan treats it as not being achieved … it may need to get the motor command that
    achieves it to support some higher action"): its plan's policy chooses from the state with
    the variable at [0], and the action succeeds on the next step if the value still holds
    (docs/decisions.md 106)."""
    plan_epsilon: float = 0.05
    """ε of the ε-greedy plan choice (§6.1.2)."""
    policy_epsilon: float = 0.05
    """ε of the ε-greedy action choice inside a plan (§6.1.3)."""
    sarsa_in_trials: bool = True
    """With learning off (evaluation, §7.2), a plan's Sarsa(λ) still updates its Q-table as
    the option executes (§5.2.2), and each new trial undoes it: the agent adapts within a
    trial, every trial starts from the checkpoint (docs/decisions.md)."""

    # --- developmental restrictions (§6.2) ---------------------------------------------------
    max_plans_per_action: int = 3
    """An action has at most three plans (§6.2.2)."""
    plan_replace_min_calls: int = 30
    """A plan may be replaced only after 30 calls (§6.2.2)."""
    plan_remove_below: float = 0.05
    """A plan whose rel(o) falls below this is removed (§6.2.2)."""
    plan_reliable: str = "o"
    """What makes a plan "sufficiently reliable" (§6.2.2's slots and criterion 1): ``"o"``,
    brel(o) of its second-order model > θ_SR at some time (§5.4.1, decisions 29–30);
    ``"dbn"``, that, or its DBN sufficiently reliable (brel(r) > θ_SR = 0.75 at some time,
    §4.2.2): §5.4.1's "a plan can *also* be sufficiently reliable if … brel(o) > θ_SR"
    (docs/decisions.md 105)."""
    plan_replace: str = "eligible"
    """Which plan a new one replaces in a full action (§6.2.2: "the plan with the lowest
    reliability rel(o) that has been called more than 30 times can be replaced"):
    ``"eligible"``, the lowest rel(o) among the plans called more than 30 times (or old);
    ``"lowest"``, the lowest rel(o) among all the action's plans not sufficiently reliable,
    replaced only if it was called more than 30 times (or is old), so a better plan is never
    replaced while a worse one waits (docs/decisions.md 100: measured and rejected)."""

    max_plan_entries: int = 300_000
    """Resource limit: a plan's Q-table may hold at most this many (state, action) entries.
    A DBN whose plan would be larger is not converted, a C_o that would make it larger is not
    adopted, and a plan that outgrows it (new landmarks) is removed (§8.3; without it the state
    spaces Q(C_o) × Q(C) × Q(X) × Q(Y) of a long run exhaust memory)."""

    ablations: Ablations = field(default_factory=Ablations)
    """Switches of §7.11."""

    def replace(self, **changes: Any) -> Params:
        """A copy with ``changes`` applied (validated)."""
        return dataclasses.replace(self, **changes)

    def __post_init__(self) -> None:
        probs = ("theta_sr", "theta_pen", "theta_ig", "theta_e", "beta_confidence",
                 "rare_event_fraction", "theta_pen_targeted", "theta_sr_targeted", "gamma",
                 "sarsa_lambda", "sarsa_alpha", "dyna_alpha", "babble_probability",
                 "plan_epsilon", "policy_epsilon", "plan_remove_below")
        for name in probs:
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"Params.{name} must lie in [0, 1], got {value!r}")
        positive = ("brel_min_successes", "min_data_points", "k_initial", "max_context_vars",
                    "stored_activations", "dbn_period", "landmark_period", "event_history",
                    "option_max_steps", "option_max_calls", "stuck_steps", "iac_window",
                    "max_plans_per_action", "max_plan_entries")
        for name in positive:
            value = getattr(self, name)
            if int(value) != value or value < 1:
                raise ValueError(f"Params.{name} must be a positive integer, got {value!r}")
        if self.landmark_period % self.dbn_period:
            raise ValueError(
                f"Params.landmark_period ({self.landmark_period}) must be a multiple of "
                f"dbn_period ({self.dbn_period}) (Algorithm 2 nests them)")
        if self.batch_lag < 0 or self.batch_lag >= self.dbn_period:
            raise ValueError(
                f"Params.batch_lag must lie in [0, dbn_period), got {self.batch_lag!r}")
        for name, choices in READINGS.items():
            if getattr(self, name) not in choices:
                raise ValueError(f"Params.{name} must be one of {', '.join(map(repr, choices))}, "
                                 f"got {getattr(self, name)!r}")
        if self.k_fixed is not None and self.k_fixed < 1:
            raise ValueError(f"Params.k_fixed must be >= 1 or None, got {self.k_fixed!r}")
        if self.derivative_zero_band < 0 or self.motor_zero_band < 0:
            raise ValueError("zero bands must be >= 0")
        if not self.step_seconds > 0:
            raise ValueError(f"Params.step_seconds must be > 0, got {self.step_seconds!r}")
        if not 0 <= self.motor_resolution < 1:
            raise ValueError(
                f"Params.motor_resolution must lie in [0, 1), got {self.motor_resolution!r}")

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (used in checkpoints)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Params:
        """Inverse of :meth:`to_dict`; unknown keys are an error naming the key."""
        data = dict(data)
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown Params field(s): {', '.join(unknown)}")
        abl = data.pop("ablations", {}) or {}
        abl_known = {f.name for f in dataclasses.fields(Ablations)}
        bad = sorted(set(abl) - abl_known)
        if bad:
            raise ValueError(f"unknown ablation switch(es): {', '.join(bad)}")
        return cls(ablations=Ablations(**abl), **data)

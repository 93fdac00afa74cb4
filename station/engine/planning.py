"""Validation and dry run: a procedure's steps checked against the station's limits and timed.

The procedure runs against a nominal model of the station: each step checks
itself (`Step.plan`), is given an estimated duration, and returns a nominal
result so that the procedure can go on. Nothing moves. The first defect
stops the plan with a ValidationError that names the step, the field, the
value and what is allowed. The operator's dry run (`checked_plan`: the
console's run and the panel's dry run and Start) first checks the design itself
(station/engine/design_checks.py): a refusal stops it with every problem of the
design; the warnings travel with the plan for the operator to confirm. The
engine's own plan does not check designs (a test or a script may run a short
design that identifies nothing).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from station.engine.context import NominalState, PlanContext, StationModel, ValidationError
from station.engine.design_checks import Finding, RefusedDesignError, check_params, long_plan
from station.engine.registry import ProcedureSpec
from station.engine.steps import Step
from station.records import RecordError
from station.session import Measurement


@dataclass(frozen=True)
class PlannedStep:
    index: int
    step: Step
    estimate_s: float
    start_s: float
    nominal: Any


@dataclass
class Plan:
    procedure: str
    params: dict[str, Any]
    steps: list[PlannedStep]
    warnings: list[Finding] = field(default_factory=list)  # of the design, for the operator to confirm

    @property
    def total_s(self) -> float:
        return sum(s.estimate_s for s in self.steps)

    @property
    def measurements(self) -> list[PlannedStep]:
        return [s for s in self.steps if s.step.key]

    def key_estimates_s(self) -> dict[str, float]:
        """Estimated seconds per measurement, including the moves and waits that lead to it."""
        out, acc = {}, 0.0
        for s in self.steps:
            acc += s.estimate_s
            if s.step.key:
                out[s.step.key] = acc
                acc = 0.0
        return out

    def to_json(self) -> dict:
        est = self.key_estimates_s()
        return {
            "procedure": self.procedure,
            "params": self.params,
            "total_s": self.total_s,
            "n_measurements": len(est),
            "measurements": [{"key": k, "estimate_s": v} for k, v in est.items()],
            "warnings": [w.to_json() for w in self.warnings],
        }


def plan_procedure(spec: ProcedureSpec, params: dict[str, Any], model: StationModel) -> Plan:
    """Validate every step and estimate its duration without hardware (ValidationError on the first defect)."""
    ctx = PlanContext(model, NominalState())
    gen = spec.func(params)
    steps: list[PlannedStep] = []
    try:
        step = gen.send(None)
        while True:
            if not isinstance(step, Step):
                raise ValidationError(f"step {ctx.index}: {step!r} is not a Step")
            ctx.step = step
            if step.key:
                ctx.claim(step.key)
            dt, nominal = step.plan(ctx)
            if isinstance(nominal, Measurement):  # the dry run's record must fit its declaration, as the run's will
                try:
                    nominal = nominal.checked()
                except RecordError as exc:
                    raise ValidationError(f"step {ctx.index} ({step.key}): {exc}") from None
            steps.append(PlannedStep(ctx.index, step, dt, ctx.state.t_s, nominal))
            ctx.state.t_s += dt
            ctx.index += 1
            step = gen.send(nominal)
    except StopIteration:
        pass
    finally:
        gen.close()
    return Plan(spec.name, params, steps)


def checked_plan(spec: ProcedureSpec, params: dict[str, Any], model: StationModel) -> Plan:
    """The operator's dry run: the design checked first (RefusedDesignError with every problem that makes it unable
    to work), then planned; the warnings go with the plan, for the operator to confirm before a start."""
    findings = check_params(spec.params, params, spec.check_design)
    if any(f.refusal for f in findings):
        raise RefusedDesignError(spec.name, findings)
    plan = plan_procedure(spec, params, model)
    plan.warnings = findings + long_plan(plan.key_estimates_s())
    return plan

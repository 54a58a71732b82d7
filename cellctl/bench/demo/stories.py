"""The demo's story files: typed, strict records (unknown keys are errors naming the key).

A story file is YAML (``stories/whole_bin.yaml`` is ``make demo``'s)::

    title: the whole-bin story
    overrides: [planner.whole.enabled=true]      # --set overrides the demo applies (--set still wins)
    stories:
      - story: "new {bin_type} bin → no plan"    # the table's title ({bin_type}: the config's sim bin)
        scenario: {new_bin: true, dirty: false}   # what the sim world looks like before the cycle
        expect: {outcome: replan_required}
        steps: [scenario, cycle, check, wait_plan, commission, clear]

Each story is one cycle; its ``steps`` run in order (the names: ``runner.STEPS``). ``--story N``
numbers the stories as the file lists them, after the variant filter (``wash``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError, model_validator

from cellctl.errors import ConfigError
from cellctl.strict_model import ConfigModel

__all__ = [
    "DEFAULT_STEPS",
    "STORIES_DIR",
    "Expect",
    "Scenario",
    "Story",
    "StoryFile",
    "chosen",
    "load_story_file",
    "story_path",
]

STORIES_DIR = Path(__file__).parent / "stories"
"""The shipped story files (``cellctl demo --stories <name>`` names one without ``.yaml``)."""

StepName = Literal[
    "scenario", "cycle", "check", "decision_path", "wash_report", "dirt_map", "wait_plan", "commission", "clear"
]

DEFAULT_STEPS: tuple[StepName, ...] = (
    "scenario",
    "cycle",
    "check",
    "decision_path",
    "wash_report",
    "dirt_map",
    "clear",
)
"""A story's steps when it names none: set the scene, play one cycle, check it, print and draw it, clear a fault."""


class Scenario(ConfigModel):
    """The sim world before a story's cycle (op ``robot/scenario``); a key left out stays as it is."""

    new_bin: bool = Field(
        default=False, description="the bin of the config's sim section (`sim.bin_type`), at its home pose"
    )
    park_offset: tuple[float, float, float] | None = Field(
        default=None, description="systematic parking offset x, y (m), yaw (degrees) in the base frame"
    )
    dirty: bool | None = Field(default=None, description="powder on the bin")
    powder_amount: float | None = Field(default=None, ge=0.0, le=1.0, description="how much powder (0-1)")
    seed: int | None = Field(default=None, description="the powder's random draw")

    def request(self, bin_type: str, home: tuple[float, float, float, float]) -> dict[str, Any]:
        """The ``SimScenarioRequest`` fields; empty when the story leaves the world as it is."""
        out: dict[str, Any] = {}
        if self.new_bin:
            out.update(bin_type=bin_type, bin_xyz_yaw=home)
        if self.dirty is not None:
            out["dirty"] = self.dirty
        if self.park_offset is not None:
            x, y, yaw_deg = self.park_offset
            out["park_offset_xy_yaw"] = (x, y, math.radians(yaw_deg))
        if self.powder_amount is not None:
            out["powder_amount"] = self.powder_amount
        if self.seed is not None:
            out["seed"] = self.seed
        return out


class Expect(ConfigModel):
    """What the story's CycleResult must say (step ``check``); a key left out is not checked."""

    outcome: str = Field(description="the cycle's outcome (completed, replan_required, ...)")
    verdict: str | None = Field(default=None, description="the bin's verdict (clean, dirty, incomplete)")
    adjusted: bool | None = Field(default=None, description="the plan was adjusted to the measured pose")
    washed: bool = Field(
        default=False,
        description="wash_and_verify: the verdict comes from at least one wash round with its three pictures",
    )


class Story(ConfigModel):
    """One cycle of the demo and what it must show."""

    story: str = Field(description="the table's title; {bin_type} is replaced by the config's sim bin")
    scenario: Scenario = Field(default_factory=Scenario, description="the sim world before the cycle")
    start: dict[str, Any] = Field(default_factory=dict, description="Start params (e.g. mode: wash_and_verify)")
    expect: Expect = Field(description="what the CycleResult must say")
    steps: list[StepName] = Field(default_factory=lambda: list(DEFAULT_STEPS), description="the steps, in order")
    wash: bool | None = Field(
        default=None, description="play only with --wash (true) or only with --no-wash (false); absent: always"
    )

    @model_validator(mode="after")
    def _one_cycle_before_its_result(self) -> Story:
        """Every step but ``scenario`` reads the cycle's result: the story plays ``cycle`` once, before them."""
        if self.steps.count("cycle") != 1:
            raise ValueError(f"steps {self.steps}: a story plays exactly one 'cycle' step")
        early = [s for s in self.steps[: self.steps.index("cycle")] if s != "scenario"]
        if early:
            raise ValueError(f"steps {self.steps}: {early} read the cycle's result, so they come after 'cycle'")
        return self

    def title(self, bin_type: str) -> str:
        return self.story.replace("{bin_type}", bin_type)


class StoryFile(ConfigModel):
    """A story file: the config the stories need and the stories in order."""

    title: str = Field(description="what the file tells (printed nowhere; for the reader)")
    overrides: list[str] = Field(default_factory=list, description="--set overrides the demo applies before yours")
    stories: list[Story] = Field(min_length=1, description="the cycles, in the order they are played")

    def played(self, wash: bool) -> list[Story]:
        """The stories of the ``--wash``/``--no-wash`` variant, in order."""
        return [s for s in self.stories if s.wash is None or s.wash == wash]


def story_path(name: str) -> Path:
    """A shipped story file by name (``whole_bin``), or a path to one's own file.

    Raises:
        ConfigError: neither a shipped name nor an existing file.
    """
    path = Path(name)
    if path.suffix in (".yaml", ".yml") and path.is_file():
        return path
    shipped = STORIES_DIR / f"{name}.yaml"
    if shipped.is_file():
        return shipped
    names = sorted(p.stem for p in STORIES_DIR.glob("*.yaml"))
    raise ConfigError(f"--stories {name!r}: neither a story file nor one of the shipped stories {names}")


def load_story_file(path: Path) -> StoryFile:
    """Read and check a story file.

    Raises:
        ConfigError: the file cannot be read, is not YAML, or has an unknown or wrong key (named, with the file).
    """
    from cellctl.config import safe_yaml_load

    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise ConfigError(f"cannot read the story file {str(path)!r}: {err}") from err
    data = safe_yaml_load(text, str(path))
    try:
        return StoryFile.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_explain(err, str(path))) from err


def _allowed(loc: tuple[Any, ...]) -> list[str]:
    """The keys allowed beside the unknown one at ``loc`` (list indexes skipped on the way down)."""
    records: dict[str, type[ConfigModel]] = {"stories": Story, "scenario": Scenario, "expect": Expect}
    model: type[ConfigModel] = StoryFile
    for part in loc[:-1]:
        if isinstance(part, int):
            continue
        nested = records.get(str(part))
        if nested is None:
            return []
        model = nested
    return sorted(model.model_fields)


def _explain(err: ValidationError, source: str) -> str:
    """One line per problem: the key's path, what is wrong, the value given (or the keys allowed there)."""
    lines = []
    for e in err.errors():
        loc = tuple(e["loc"])
        key = ".".join(str(x) for x in loc) or "(top level)"
        if e["type"] == "extra_forbidden":
            lines.append(f"{source}: unknown key {key!r}; allowed keys here: {_allowed(loc)}")
        else:
            shown = repr(e.get("input"))
            lines.append(f"{source}: key {key!r}: {e['msg']} (got {shown[:77] + '...' if len(shown) > 80 else shown})")
    return "\n".join(lines)


def chosen(stories: list[Story], wanted: list[int] | None) -> list[tuple[int, Story]]:
    """The stories to play with their numbers: all, or story 1 (it plans the bin) and the ``wanted`` ones.

    Raises:
        ConfigError: a story number the file does not have.
    """
    bad = [n for n in wanted or [] if not 1 <= n <= len(stories)]
    if bad:
        raise ConfigError(f"--story {bad[0]}: this demo has stories 1-{len(stories)}")
    keep = {1, *wanted} if wanted else set(range(1, len(stories) + 1))
    return [(n, st) for n, st in enumerate(stories, 1) if n in keep]

"""The kinds of `factr2 train` flag whose text is parsed into a value of its own (policies.training.flags'
Flag for the rest): ratios, source weights, episode ids, thresholds, model-config overrides and the
observation noise, each written back by argv() to text that parses to the same value."""

from __future__ import annotations

from hardware.errors import UserError
from policies.data.sampler import parse_ratio, parse_source_weights
from policies.labels.label_flags import add_threshold_arguments, thresholds_arg
from policies.labels.labelling import TARE_DEFAULT, LabelChoice
from policies.models.config import settable
from policies.training.flags import Flag
from policies.training.regularise import format_obs_noise, parse_obs_noise


class ParsedFlag(Flag):
    """A flag whose text parse() turns into a value (None when not given); a ValueError becomes one line
    with `example` as the fix."""

    example = ""

    @staticmethod
    def parse(text: str):
        raise NotImplementedError

    def value(self, ns, dest: str):
        text = getattr(ns, dest)
        if text is None:
            return None
        try:
            return self.parse(text)
        except ValueError as e:
            raise UserError(f"{self.name}: {e}", fix=f"e.g. {self.name} {self.example}") from None


class RatioFlag(ParsedFlag):
    """--ratio F:PC:C or a preset name -> (w_F, w_PC, w_C); written back as F:PC:C. presets: the names offered
    (the terminal app cycles through them after "default", the method's own)."""

    presets = ("PC", "C", "PC+C", "uniform")
    example = "1:5:1"
    parse = staticmethod(parse_ratio)

    def argv(self, value, default) -> list[str]:
        return [] if value is None else [self.name, ":".join(str(float(w)) for w in value)]


class SourceWeightsFlag(ParsedFlag):
    """--source-weights demo=1,policy=1,pre=0.25,operator=2 (any subset) -> the four weights (rollout
    recordings with interventions: policies/data/sampler.py); written back in full."""

    example = "pre=0,operator=3"
    parse = staticmethod(parse_source_weights)

    def argv(self, value, default) -> list[str]:
        from hardware.recording.interventions import SOURCE_NAMES

        return [] if value is None else [self.name, ",".join(f"{n}={float(w)}" for n, w in
                                                             zip(SOURCE_NAMES, value))]


class EpisodesFlag(ParsedFlag):
    """--episodes FILE.mcap#N-M,... -> the ids of the episodes to train on (as policies.data.recordings'
    episode_id names them); written back one by one."""

    example = "peg-insert-sim-piper-seed1.mcap#0-11"

    @staticmethod
    def parse(text: str):
        from policies.data.recordings import parse_episode_ids

        return parse_episode_ids(text)

    def argv(self, value, default) -> list[str]:
        return [] if value is None else [self.name, ",".join(value)]


class ThresholdsFlag(Flag):
    """--thresholds recording|next|LOW:HIGH and --no-tare (policies.labels.label_flags, shared with the label
    commands) -> a LabelChoice."""

    def names(self) -> list[str]:
        return ["--thresholds", "--no-tare", "--contact-score"]

    def add(self, p, dest: str, default) -> None:
        add_threshold_arguments(p)

    def value(self, ns, dest: str):
        return thresholds_arg(ns)

    def argv(self, value, default) -> list[str]:
        th, tare, score = ((value.thresholds, value.tare, value.score) if isinstance(value, LabelChoice)
                           else (value, TARE_DEFAULT, "l1"))
        # None: resolve_thresholds' "next" (its library default)
        text = "next" if th is None else th if isinstance(th, str) else ":".join(str(float(x)) for x in th)
        return (["--thresholds", text] + (["--no-tare"] if tare == "off" else [])
                + (["--contact-score", score] if score != "l1" else []))


class OverridesFlag(Flag):
    """--set FIELD=VALUE (repeated) -> {field: value} over the preset's policy config (settable fields)."""

    def add(self, p, dest: str, default) -> None:
        p.add_argument(self.name, action="append", default=None, metavar="FIELD=VALUE", dest=dest,
                       help=self._help())

    def value(self, ns, dest: str):
        items = getattr(ns, dest)
        return None if items is None else parse_overrides(items)

    def argv(self, value, default) -> list[str]:
        return [a for k, v in (value or {}).items() for a in (self.name, f"{k}={v}")]


def parse_overrides(items: list[str]) -> dict:
    """["hidden=128", ...] -> {"hidden": 128, ...}, typed as PolicyConfig's fields; UserError for a field the
    run fills itself or a value of the wrong type."""
    types = settable()
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key not in types:
            raise UserError(f"--set {item!r}: not FIELD=VALUE of a settable policy config field",
                            fix="see policies/models/config.py, e.g. --set hidden=128")
        try:
            out[key] = (value.lower() in ("1", "true", "yes")) if types[key] is bool else types[key](value)
        except ValueError:
            raise UserError(f"--set {item!r}: {value!r} is not a {types[key].__name__}") from None
    return out


class ObsNoiseFlag(ParsedFlag):
    """--obs-noise state=0.05,objects=0.05,force=0.1 -> {input: sigma} (policies.training.regularise);
    written back the same way."""

    example = "state=0.05,objects=0.05,force=0.1"
    parse = staticmethod(parse_obs_noise)

    def argv(self, value, default) -> list[str]:
        return [self.name, format_obs_noise(value)] if value else []

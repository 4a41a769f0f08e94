"""mop_core/config.py: typed configs from plain mappings; every error names its full dotted key."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from mop_core.config import (
    ConfigError,
    InputFileError,
    first_line,
    from_mapping,
    keys_under,
    require,
    require_unique,
    to_dict,
)


@dataclass(frozen=True)
class Inner:
    batch: int
    rate: float = 0.5

    def __post_init__(self) -> None:
        require(self.batch > 0, "batch", "a positive integer", self.batch)


@dataclass(frozen=True)
class Outer:
    name: str
    inner: Inner
    sizes: tuple[int, ...] = (1, 2)
    flag: bool = False
    target: float | None = None
    extra: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        require(len(self.sizes) > 0, "sizes", "a non-empty list", list(self.sizes))
        if self.name == "prefixed":  # an error that already carries the section's prefix
            raise ConfigError("outer.name: already prefixed")
        if self.name == "value":
            raise ValueError("name: a plain ValueError is no ConfigError")


def test_require_and_require_unique_name_the_key_and_value():
    require(True, "k", "anything", 1)
    with pytest.raises(ConfigError) as err:
        require(False, "train.seeds", "a non-empty list", [])
    assert str(err.value) == "train.seeds: expected a non-empty list, got []"
    require_unique([0, 1, 2], "seeds")
    with pytest.raises(ConfigError) as err:
        require_unique([0, 1, 0], "distill.seeds")
    assert str(err.value) == "distill.seeds: expected a list without repeats, got [0, 1, 0] (0 twice)"
    assert issubclass(ConfigError, ValueError) and issubclass(InputFileError, ValueError)


def test_from_mapping_builds_nested_configs_and_coerces_lists_and_numbers():
    config = from_mapping(Outer, {"name": "a", "inner": {"batch": 3, "rate": "3e-4"}, "sizes": [4, 5],
                                  "flag": True, "target": 2, "extra": {"x": 1}}, "outer")
    assert config == Outer("a", Inner(3, 3e-4), (4, 5), True, 2.0, {"x": 1})
    assert isinstance(config.inner.rate, float) and isinstance(config.target, float)
    assert isinstance(config.sizes, tuple)
    defaults = from_mapping(Outer, {"name": "b", "inner": {"batch": 1}, "target": None}, "outer")
    assert defaults == Outer("b", Inner(1, 0.5), (1, 2), False, None, {})


@pytest.mark.parametrize("mapping,message", [
    ({"name": "a", "inner": {"batch": 1}, "sise": [1]}, "outer.sise: unknown parameter; known: extra, flag, inner, "
                                                       "name, sizes, target"),
    ({"inner": {"batch": 1}}, "outer.name: missing required parameter"),
    ({"name": "a", "inner": {}}, "outer.inner.batch: missing required parameter"),
    ({"name": "a", "inner": {"batch": 1, "size": 2}}, "outer.inner.size: unknown parameter"),
    ({"name": "a", "inner": 3}, "outer.inner: expected a mapping of Inner fields, got 3"),
    ({"name": 1, "inner": {"batch": 1}}, "outer.name: expected a string, got 1"),
    ({"name": "a", "inner": {"batch": True}}, "outer.inner.batch: expected an integer, got True"),
    ({"name": "a", "inner": {"batch": 1.5}}, "outer.inner.batch: expected an integer, got 1.5"),
    ({"name": "a", "inner": {"batch": 1, "rate": "fast"}}, "outer.inner.rate: expected a number, got 'fast'"),
    ({"name": "a", "inner": {"batch": 1, "rate": False}}, "outer.inner.rate: expected a number, got False"),
    ({"name": "a", "inner": {"batch": 1, "rate": float("inf")}}, "outer.inner.rate: expected a finite number"),
    ({"name": "a", "inner": {"batch": 1, "rate": "nan"}}, "outer.inner.rate: expected a finite number"),
    ({"name": "a", "inner": {"batch": 1}, "flag": 1}, "outer.flag: expected true or false, got 1"),
    ({"name": "a", "inner": {"batch": 1}, "sizes": 3}, "outer.sizes: expected a list, got 3"),
    ({"name": "a", "inner": {"batch": 1}, "sizes": [1, "2"]}, "outer.sizes[1]: expected an integer, got '2'"),
    ({"name": "a", "inner": {"batch": 1}, "target": "x"}, "outer.target: expected a number, got 'x'"),
    ({"name": "a", "inner": {"batch": 1}, "extra": [1]}, "outer.extra: expected a mapping, got [1]"),
])
def test_from_mapping_errors_name_the_dotted_key(mapping, message):
    with pytest.raises(ConfigError) as err:
        from_mapping(Outer, mapping, "outer")
    assert str(err.value).startswith(message)


def test_post_init_errors_are_prefixed_once_with_the_section():
    with pytest.raises(ConfigError) as err:  # Inner's own check, re-raised under the full key
        from_mapping(Outer, {"name": "a", "inner": {"batch": 0}}, "collect.outer")
    assert str(err.value) == "collect.outer.inner.batch: expected a positive integer, got 0"
    with pytest.raises(ConfigError) as err:
        from_mapping(Outer, {"name": "a", "inner": {"batch": 1}, "sizes": []}, "outer")
    assert str(err.value) == "outer.sizes: expected a non-empty list, got []"
    with pytest.raises(ConfigError) as err:
        from_mapping(Outer, {"name": "prefixed", "inner": {"batch": 1}}, "outer")
    assert str(err.value) == "outer.name: already prefixed"
    with pytest.raises(ValueError) as err:  # only ConfigErrors are re-keyed
        from_mapping(Outer, {"name": "value", "inner": {"batch": 1}}, "outer")
    assert type(err.value) is ValueError and str(err.value).startswith("name:")


def test_from_mapping_refuses_a_section_that_is_not_a_mapping():
    with pytest.raises(ConfigError, match=r"^study: expected a mapping, got \['stand'\]$"):
        from_mapping(Inner, ["stand"], "study")


def test_keys_under_reports_library_errors_under_their_section():
    with pytest.raises(ConfigError) as err:
        with keys_under("train_teachers"):
            require(False, "pbrl.batch_size", "at most 10", 64)
    assert str(err.value) == "train_teachers.pbrl.batch_size: expected at most 10, got 64"
    with pytest.raises(ConfigError) as err:
        with keys_under("distill"):
            raise ConfigError("distill.batch_size: already under its section")
    assert str(err.value) == "distill.batch_size: already under its section"
    with pytest.raises(KeyError):  # other errors pass through untouched
        with keys_under("distill"):
            raise KeyError("x")
    with keys_under("distill"):
        pass


def test_to_dict_gives_plain_nested_lists_and_dicts():
    config = Outer("a", Inner(2), (3, 4), extra={"k": (1, 2)})
    plain = to_dict(config)
    assert plain == {"name": "a", "inner": {"batch": 2, "rate": 0.5}, "sizes": [3, 4], "flag": False,
                     "target": None, "extra": {"k": [1, 2]}}
    assert from_mapping(Outer, plain, "outer") == Outer("a", Inner(2), (3, 4), extra={"k": [1, 2]})


def test_first_line_is_the_type_and_the_first_line_of_the_message():
    assert first_line(EOFError("Ran out of input\nmore detail")) == "EOFError: Ran out of input"
    assert first_line(KeyError()) == "KeyError"
    assert first_line(ValueError("  \n")) == "ValueError"

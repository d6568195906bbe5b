"""Environment sets and testbeds as the user describes them: presets, inline values, TOML files.

The Forecast idea is a *set of environments of interest* (Section 5 of the paper); this module
turns every way of naming such a set into one value, :class:`EnvironmentSet`, so that every verb
and every library function accepts the same descriptions (``docs/environments.md``):

- an :class:`~forecast_design.params.Environment` or an :class:`EnvironmentSet`;
- a preset name (``soft``) or a comma list of them (``soft,stiff``), ``random:N``;
- inline values ``k_e=20,J_e=0.02[,d_e=...][,J_l=...][,d_l=...][,locked=true][,name=...]``;
- a TOML file: one ``[environment]`` table or ``[[environment]]`` tables, whose values may be
  grids (``{log = [0.1, 100], n = 7}``, ``{lin = [a, b], n = N}``, a list) or nominal values with
  relative uncertainty (``{nominal = 5.0, rel = 0.2}``); a run's TOML (its ``[environment]``);
- an iterable (or a name -> environment mapping) mixing all of these.

The testbed is resolved the same way by :func:`resolve_testbed`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from .errors import ExperimentFormatError, ParameterError
from .experiment_io import FORMAT
from .experiment_io import parse_toml as _parse_toml
from .experiment_io import read_toml_document as _read_toml
from .limits import check_limit, limit_of
from .plausibility import benchtop_warnings
from .params import (
    ENVIRONMENT_PRESETS,
    TABLE1_LINK,
    Design,
    Environment,
    Testbed,
    critically_damped,
    check_number,
    environment_preset,
)

__all__ = [
    "EnvironmentSet",
    "resolve_environments",
    "resolve_testbed",
    "document_design",
    "ENVIRONMENT_KEYS",
    "TESTBED_KEYS",
    "RANDOM_RANGES",
]

#: Keys of one environment in an inline value or a ``[[environment]]`` table.
ENVIRONMENT_KEYS = ("name", "J_e", "d_e", "k_e", "J_l", "d_l", "locked")
#: Keys of a testbed file's ``[testbed]`` and of inline testbed values: the experiment format's three
#: and, optionally, the SEA's link (J_l, d_l; the default of every environment that sets none).
TESTBED_KEYS = ("J_m", "d_m", "k", "J_l", "d_l")
#: ``random:N`` draws log-uniformly in these ranges (k_e [N m/rad], J_e [kg m^2]), d_e critical.
RANDOM_RANGES = {"k_e": (0.1, 1000.0), "J_e": (1e-3, 1.0)}
_NUMERIC = ("J_e", "d_e", "k_e", "J_l", "d_l")
_CRITICAL_NOTE = "d_e not given: critically damped, d_e = 2 sqrt(k_e J_e) (Section 5's rule)"


@dataclass(frozen=True, slots=True)
class EnvironmentSet:
    """A named, ordered set of environments (the paper's environments of interest).

    Parameters
    ----------
    names : tuple of str
        One unique label per environment (preset name, grid point, file table name...).
    environments : tuple of Environment
        The environments, in the order given.
    source : str or None
        Where the set came from (a file path or the spec text), for messages.
    notes : tuple of str
        Defaults that were filled in (e.g. a critically damped d_e); the CLI prints them.

    Notes
    -----
    ``len(s)``, ``for name, env in s`` and ``s.items()`` work as for a mapping of name to
    environment; ``s[name]`` returns one environment.
    """

    names: tuple[str, ...]
    environments: tuple[Environment, ...]
    source: str | None = None
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))
        object.__setattr__(self, "environments", tuple(self.environments))
        object.__setattr__(self, "notes", tuple(dict.fromkeys(self.notes)))
        where = f"{self.source}: " if self.source else ""
        if len(self.names) != len(self.environments):
            raise ParameterError(f"{where}{len(self.names)} names for {len(self.environments)} environments",
                                 name="environments")
        for env in self.environments:
            if not isinstance(env, Environment):
                raise ParameterError(f"{where}not an Environment: {env!r}", name="environments", value=env)
        seen: set[str] = set()
        for name in self.names:
            if name in seen:
                raise ParameterError(f"{where}environment name '{name}' appears twice with different values",
                                     name="name", value=name)
            seen.add(name)

    def __len__(self) -> int:
        return len(self.names)

    def __iter__(self) -> Iterator[tuple[str, Environment]]:
        return iter(zip(self.names, self.environments))

    def items(self) -> Iterator[tuple[str, Environment]]:
        """The ``(name, Environment)`` pairs, in order."""
        return iter(self)

    def __getitem__(self, name: str) -> Environment:
        try:
            return self.environments[self.names.index(name)]
        except ValueError:
            raise ParameterError(f"no environment '{name}' in the set; it holds: {', '.join(self.names)}",
                                 name="environment", value=name) from None

    def single(self, what: str = "this command") -> tuple[str, Environment]:
        """The one ``(name, Environment)`` of a one-element set.

        Parameters
        ----------
        what : str
            Who needs one environment, for the message.

        Returns
        -------
        (str, Environment)
            The name and the environment.

        Raises
        ------
        ParameterError
            If the set holds several environments (never silently keeping one of them).
        """
        if len(self) != 1:
            raise ParameterError(f"{what} needs one environment, got {len(self)} ({', '.join(self.names[:6])}"
                                 f"{', ...' if len(self) > 6 else ''})", name="environment",
                                 value=self.names)
        return self.names[0], self.environments[0]

    def designs(self, testbed: Testbed | None = None, **kwargs: Any) -> list[tuple[str, Design]]:
        """One :class:`~forecast_design.params.Design` per environment.

        Parameters
        ----------
        testbed : Testbed or None
            The testbed (None: Table 1).
        **kwargs
            ``controller`` and ``compensator`` of the designs.

        Returns
        -------
        list of (str, Design)
        """
        tb = testbed if testbed is not None else Testbed()
        return [(name, Design(testbed=tb, environment=env, **kwargs)) for name, env in self]

    def to_mapping(self) -> dict[str, Any]:
        """``{"environment": [{"name", "J_e", "d_e", "k_e", "J_l", "d_l", "locked"}, ...]}`` (SI units)."""
        return {"environment": [{"name": name, **env.to_mapping()} for name, env in self]}

    def to_toml(self) -> str:
        """The set as an environment-set TOML file (``[[environment]]`` tables, 17 digits).

        Returns
        -------
        str
            TOML text that :func:`resolve_environments` reads back to an equal set.
        """
        lines = ["# environment set (docs/environments.md); units: kg m^2, N m s/rad, N m/rad"]
        for row in self.to_mapping()["environment"]:
            lines.append("")
            lines.append("[[environment]]")
            for key, value in row.items():
                if isinstance(value, bool):
                    text = "true" if value else "false"
                elif isinstance(value, str):
                    text = '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
                else:
                    text = repr(float(value))
                lines.append(f"{key} = {text}")
        return "\n".join(lines) + "\n"


# --- resolution -------------------------------------------------------------------------


def resolve_environments(spec: Any, *, testbed: Testbed | None = None, seed: int = 0) -> EnvironmentSet:
    """Turn any description of environments into an :class:`EnvironmentSet`.

    Parameters
    ----------
    spec : Environment, EnvironmentSet, str, path, mapping or iterable
        An Environment; an EnvironmentSet; a preset name (``"soft"``); a comma list of presets
        (``"soft,stiff"``); ``"random:N"`` (N environments drawn log-uniformly, k_e in
        [0.1, 1000] N m/rad, J_e in [1e-3, 1] kg m^2, critically damped); inline values
        ``"k_e=20,J_e=0.02[,d_e=..][,J_l=..][,d_l=..][,locked=true][,name=..]"``; a TOML
        file (``docs/environments.md``); a mapping of names to any of these; or an iterable
        mixing them (concatenated in order; an identical repeat is kept once).
    testbed : Testbed or None
        The testbed the environments attach to. When it carries the SEA's link (``J_l``,
        ``d_l``), J_l and d_l default to it, and presets (defined on Table 1's link) take it;
        otherwise they default to Table 1's link (0.0018 kg m^2, 0.35 N m s/rad) or, for the
        tables of a file with a ``[testbed]`` carrying a link, to that file's.
    seed : int
        Seed of ``random:N``.

    Returns
    -------
    EnvironmentSet
        The set; ``notes`` says which defaults were filled in (d_e critically damped).

    Raises
    ------
    ParameterError
        Unknown preset, malformed inline value or an empty set (one line naming it).
    ExperimentFormatError
        Malformed TOML file (one line naming the file, the table and the key).

    Examples
    --------
    >>> s = resolve_environments("soft,k_e=20,J_e=0.02")
    >>> s.names, round(s["k_e=20,J_e=0.02"].d_e, 4)
    (('soft', 'k_e=20,J_e=0.02'), 1.2649)
    """
    return _resolve(spec, _link_defaults(testbed), seed)


def _resolve(spec: Any, link: dict[str, float], seed: int) -> EnvironmentSet:
    parts = _collect(spec, link, seed)
    if not parts:
        raise ParameterError(f"the environment set is empty (got {spec!r})", name="envs", value=spec)
    names: list[str] = []
    envs: list[Environment] = []
    notes: list[str] = []
    sources: list[str] = []
    for part in parts:
        notes += part.notes
        if part.source and part.source not in sources:
            sources.append(part.source)
        for name, env in part:
            if name in names:
                if envs[names.index(name)] == env:
                    continue        # the same environment named twice: keep it once
                raise ParameterError(f"environment name '{name}' given twice with different values "
                                     f"(from {', '.join(sources)})", name="name", value=name)
            names.append(name)
            envs.append(env)
    return EnvironmentSet(tuple(names), tuple(envs), source=", ".join(sources) or None, notes=tuple(notes))


def _link_defaults(testbed: Any) -> dict[str, float]:
    base = dict(zip(("J_l", "d_l"), TABLE1_LINK))
    for key in ("J_l", "d_l"):
        value = getattr(testbed, key, None)
        if value is not None:
            base[key] = float(value)
    return base


def _collect(spec: Any, link: dict[str, float], seed: int) -> list[EnvironmentSet]:
    if isinstance(spec, EnvironmentSet):
        return [spec]
    if isinstance(spec, Environment):
        return [EnvironmentSet((_label(spec),), (spec,), source=None)]
    if isinstance(spec, Design):
        return [EnvironmentSet((_label(spec.environment),), (spec.environment,), source=None)]
    if isinstance(spec, (str, os.PathLike)):
        return _from_text(spec, link, seed)
    if isinstance(spec, Mapping):
        out = []
        for name, value in spec.items():
            part = _resolve(value, link, seed)
            if len(part) == 1:
                part = EnvironmentSet((str(name),), part.environments, part.source, part.notes)
            else:
                part = EnvironmentSet(tuple(f"{name}/{n}" for n in part.names), part.environments,
                                      part.source, part.notes)
            out.append(part)
        return out
    if spec is None:
        raise ParameterError("no environment given (None)", name="envs", value=spec)
    try:
        items = list(spec)
    except TypeError:
        raise ParameterError(f"cannot read environments from {type(spec).__name__} {spec!r}; give an "
                             f"Environment, a preset name, inline k_e=..,J_e=.. values or a TOML file",
                             name="envs", value=spec) from None
    out = []
    for item in items:
        out += _collect(item, link, seed)
    return out


def _label(env: Environment) -> str:
    for name, preset in ENVIRONMENT_PRESETS.items():
        if preset == env:
            return name
    if env.locked:
        return "locked"
    return f"k_e={env.k_e:.6g},J_e={env.J_e:.6g},d_e={env.d_e:.6g}"


def _from_text(spec: str | os.PathLike, link: dict[str, float], seed: int) -> list[EnvironmentSet]:
    text = os.fspath(spec).strip()
    if isinstance(spec, os.PathLike) or _looks_like_file(text):
        return [_from_file(Path(text), link)]
    member = _file_member(text) if "," not in text else None
    if member is not None:
        return [_member(_from_file(Path(member[0]), link), member[1], member[0])]
    if "=" in text:
        return [_from_inline(text, link)]
    out = []
    for item in (t.strip() for t in text.split(",")):
        if not item:
            continue
        if item.startswith("random:"):
            out.append(_random(item, seed))
        elif _looks_like_file(item):
            out.append(_from_file(Path(item), link))
        elif _file_member(item) is not None:
            path, name = _file_member(item)
            out.append(_member(_from_file(Path(path), link), name, path))
        else:
            out.append(EnvironmentSet((item,), (_with_link(environment_preset(item), link),), source=None))
    return out


def _with_link(env: Environment, link: Mapping[str, float]) -> Environment:
    """A preset on the default link takes the testbed's (the link belongs to the SEA, not the preset)."""
    if not env.link_given and (link["J_l"], link["d_l"]) != TABLE1_LINK:
        return dataclasses.replace(env, J_l=link["J_l"], d_l=link["d_l"])
    return env


def _file_member(text: str) -> tuple[str, str] | None:
    """``FILE.toml#NAME`` -> (FILE.toml, NAME): one member of an environment-set file, or None."""
    path, sep, name = text.rpartition("#")
    return (path, name.strip()) if sep and path.lower().endswith(".toml") and name.strip() else None


def _member(envset: EnvironmentSet, name: str, path: str) -> EnvironmentSet:
    if name not in envset.names:
        raise ParameterError(f"{path}: no environment named '{name}' (it has {', '.join(envset.names)})",
                             name="envs", value=name)
    return EnvironmentSet((name,), (envset[name],), source=envset.source, notes=envset.notes)


def _looks_like_file(text: str) -> bool:
    return text.lower().endswith(".toml") or (text not in ENVIRONMENT_PRESETS and "=" not in text
                                              and "," not in text and os.path.isfile(text))


def _random(item: str, seed: int) -> EnvironmentSet:
    try:
        count = int(item.split(":", 1)[1])
    except ValueError:
        count = -1
    if count < 1:
        raise ParameterError(f"'{item}': expected random:N with an integer N >= 1", name="envs", value=item)
    check_limit(f"'{item}': N", "random_environments", count)
    check_limit("seed", "seed", seed)
    rng = np.random.default_rng(seed)
    (k_lo, k_hi), (j_lo, j_hi) = RANDOM_RANGES["k_e"], RANDOM_RANGES["J_e"]
    names, envs = [], []
    for i in range(count):
        k_e = float(10 ** rng.uniform(math.log10(k_lo), math.log10(k_hi)))
        J_e = float(10 ** rng.uniform(math.log10(j_lo), math.log10(j_hi)))
        names.append(f"random{i}")
        envs.append(Environment(J_e=J_e, d_e=critically_damped(k_e, J_e), k_e=k_e))
    return EnvironmentSet(tuple(names), tuple(envs), source=item)


def _bool(text: str, where: str) -> bool:
    lowered = text.strip().lower()
    if lowered in ("true", "1", "yes"):
        return True
    if lowered in ("false", "0", "no"):
        return False
    raise ParameterError(f"{where}locked must be true or false, got {text!r}", name="locked", value=text)


def _from_inline(text: str, link: dict[str, float]) -> EnvironmentSet:
    where = f"environment '{text}': "
    values: dict[str, Any] = {}
    for item in (t.strip() for t in text.split(",")):
        if not item:
            continue
        key, sep, value = (s.strip() for s in item.partition("="))
        if not sep:
            raise ParameterError(f"{where}expected key=value items (e.g. k_e=20,J_e=0.02), got {item!r}",
                                 name="environment", value=text)
        if key not in ENVIRONMENT_KEYS:
            raise ParameterError(f"{where}unknown key '{key}'; allowed: {', '.join(ENVIRONMENT_KEYS)}",
                                 name=key, value=text)
        if key in values:
            raise ParameterError(f"{where}key '{key}' given twice", name=key, value=text)
        if key == "name":
            values[key] = value
        elif key == "locked":
            values[key] = _bool(value, where)
        else:
            try:
                values[key] = float(value)
            except ValueError:
                raise ParameterError(f"{where}{key} must be a number, got {value!r}", name=key,
                                     value=value) from None
    name = values.pop("name", text)
    env, notes = _build(values, link, where)
    return EnvironmentSet((name,), (env,), source=None, notes=notes)


def _build(values: Mapping[str, Any], link: Mapping[str, float], where: str) -> tuple[Environment, tuple[str, ...]]:
    """One Environment from checked keys; fills d_e (critical), J_l, d_l and says so."""
    locked = values.get("locked", False)
    notes: tuple[str, ...] = ()
    kwargs = {key: values[key] for key in _NUMERIC if key in values}
    if not locked:
        for key in ("k_e", "J_e"):
            if key not in kwargs:
                raise ParameterError(f"{where}missing {key} (or give locked=true)", name=key)
        if "d_e" not in kwargs:
            for key in ("k_e", "J_e"):
                check_number("[environment]", key, kwargs[key])
            kwargs["d_e"] = critically_damped(kwargs["k_e"], kwargs["J_e"])
            notes = (_CRITICAL_NOTE,)
    else:
        for key in ("J_e", "d_e", "k_e"):
            kwargs.setdefault(key, 0.0)
    if (link["J_l"], link["d_l"]) != TABLE1_LINK:   # the testbed's link (Table 1's: the unset default)
        kwargs = {**link, **kwargs}
    try:
        return Environment(**kwargs, locked=bool(locked)), notes
    except ParameterError as exc:
        raise ParameterError(f"{where}{exc}", name=exc.name, value=exc.value) from None


# --- TOML files ---------------------------------------------------------------------------


def _read(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise ExperimentFormatError(f"{path}: environment file not found", path=str(path))
    return _read_toml(path)


def _from_file(path: Path, link: dict[str, float]) -> EnvironmentSet:
    label = str(path)
    doc = _read(path)
    if "format" in doc:
        return EnvironmentSet((path.stem,), (_formatted_design(doc, label)[1],), source=label)
    for key in doc:
        if key not in ("environment", "testbed", "description"):
            raise ExperimentFormatError(f"{label}: unknown top-level key '{key}'; allowed: environment, "
                                        f"testbed, description", path=label, key=key)
    if "environment" not in doc:
        raise ExperimentFormatError(f"{label}: no [environment] table or [[environment]] tables",
                                    path=label, key="environment")
    if (link["J_l"], link["d_l"]) == TABLE1_LINK and isinstance(doc.get("testbed"), Mapping):
        own = _testbed_table(doc["testbed"], label).link    # the file's testbed: the default of its tables
        if own is not None:
            link = {"J_l": own[0], "d_l": own[1]}
    tables = doc["environment"]
    single = isinstance(tables, Mapping)
    if single:
        tables = [tables]
    if not isinstance(tables, list) or not tables:
        raise ExperimentFormatError(f"{label}: environment must be a table or a list of [[environment]] "
                                    f"tables, got {tables!r}", path=label, key="environment")
    names: list[str] = []
    envs: list[Environment] = []
    notes: list[str] = []
    if len(tables) > limit_of("environments"):
        raise ExperimentFormatError(f"{label}: {len(tables)} [[environment]] tables, more than a set may have "
                                    f"({limit_of('environments')})", path=label, key="environment")
    for i, table in enumerate(tables):
        section = "[environment]" if single else f"[[environment]] #{i + 1}"
        for name, env, note in _expand_table(table, section, label, link, default_name=
                                             path.stem if single else f"{path.stem}{i + 1}"):
            if name in names:
                raise ExperimentFormatError(f"{label}: {section} name '{name}' is used twice",
                                            path=label, key="environment.name")
            names.append(name)
            envs.append(env)
            notes += note
            if len(envs) > limit_of("environments"):
                raise ExperimentFormatError(f"{label}: more than {limit_of('environments')} environments over its "
                                            "tables, more than a set may have", path=label, key="environment")
    return EnvironmentSet(tuple(names), tuple(envs), source=label, notes=tuple(notes))


def _formatted_design(doc: Mapping[str, Any], label: str) -> tuple[Testbed, Environment]:
    """Testbed and environment of a run's TOML (its CSV unread) or of another format's file
    (e.g. a simulation scenario, :func:`document_design`). A run's testbed carries its environment's
    link (the SEA's), so ``--testbed RUN.toml`` gives it to the environments it is used with."""
    if doc["format"] == FORMAT:
        design = _parse_toml(doc, label)[0]
        env = design.environment
        return dataclasses.replace(design.testbed, J_l=env.J_l, d_l=env.d_l), env
    testbed, env, _ = document_design(doc, label)
    return testbed, env


def document_design(doc: Mapping[str, Any], source: str | None, *,
                    what: str = "a scenario") -> tuple[Testbed, Environment, tuple[str, ...]]:
    """The nominal testbed and environment of a file in a toolbox format (a scenario): the one resolution.

    ``testbed`` is a ``[testbed]`` table (``J_m``, ``d_m``, ``k`` and optionally the link ``J_l``,
    ``d_l``) or a string naming one as ``--testbed`` does (a testbed file, relative to the file's
    folder; inline ``k=..``; ``table1``). ``environment`` is an ``[environment]`` table (its ``J_l``,
    ``d_l`` may be left to the testbed's link) or a string naming one environment (a preset, inline
    values, a file holding one, ``FILE.toml#NAME``), whose defaults come from the testbed's link.

    Parameters
    ----------
    doc : Mapping
        The parsed document.
    source : str or None
        Its file, for relative paths and messages.
    what : str
        Who needs one environment, for the message.

    Returns
    -------
    (Testbed, Environment, tuple of str)
        The testbed, the environment and notes on the defaults filled in.

    Raises
    ------
    ExperimentFormatError
        One line naming the file and the key.
    """
    prefix = f"{source}: " if source else ""
    value = doc.get("testbed")
    if isinstance(value, str):
        with _naming(prefix, "testbed", value, source):
            testbed = resolve_testbed(_beside(value, source))
    elif isinstance(value, Mapping):
        testbed = _testbed_table(value, source, full=True)
    else:
        raise ExperimentFormatError(f"{prefix}missing required table [testbed]" if value is None else
                                    f"{prefix}[testbed] must be a table or a testbed spec, got {value!r}",
                                    path=source, key="testbed")
    value = doc.get("environment")
    if isinstance(value, str):
        with _naming(prefix, "environment", value, source):
            envset = resolve_environments(_beside(value, source), testbed=testbed)
            return testbed, envset.single(what)[1], envset.notes
    if not isinstance(value, Mapping):
        raise ExperimentFormatError(f"{prefix}missing required table [environment]" if value is None else
                                    f"{prefix}[environment] must be a table or an environment spec, got {value!r}",
                                    path=source, key="environment")
    if testbed.link is not None:
        value = {"J_l": testbed.J_l, "d_l": testbed.d_l, **value}
    return testbed, Environment.from_mapping(value, source=source), ()


def _beside(spec: str, source: str | None) -> str:
    """A file a document names (``F.toml``, ``F.toml#NAME``), relative to the document's folder."""
    spec = spec.strip()
    path, sep, member = spec.rpartition("#") if ".toml#" in spec.lower() else (spec, "", "")
    if path.lower().endswith(".toml") and source is not None and not os.path.isabs(path):
        return os.path.join(os.path.dirname(source), path) + sep + member
    return spec


@contextlib.contextmanager
def _naming(prefix: str, key: str, value: str, source: str | None) -> Iterator[None]:
    try:
        yield
    except (ParameterError, ExperimentFormatError) as exc:
        raise ExperimentFormatError(f"{prefix}{key} = {value!r}: {str(exc).splitlines()[0]}", path=source,
                                    key=key) from None


def _testbed_table(table: Mapping[str, Any], label: str | None, *, full: bool = False) -> Testbed:
    """A testbed file's or a scenario's ``[testbed]`` (with the optional link), plausibility warnings said.
    ``full``: all three keys required (a scenario); else missing keys keep Table 1's (a testbed file)."""
    if not full and isinstance(table, Mapping):
        table = {**Testbed().to_mapping(), **table}
    testbed = Testbed.from_mapping(table, source=label, link=True)
    _warn_benchtop(testbed, f"{label}: [testbed]" if label else "[testbed]")
    return testbed


def _warn_benchtop(testbed: Testbed, where: str) -> None:
    benchtop_warnings({"J_m": testbed.J_m, "d_m": testbed.d_m, "k": testbed.k, "J_l": testbed.J_l,
                       "d_l": testbed.d_l}, where)


def _expand_table(table: Any, section: str, label: str, link: dict[str, float], *,
                  default_name: str) -> Iterator[tuple[str, Environment, tuple[str, ...]]]:
    def fail(message: str, key: str) -> ExperimentFormatError:
        return ExperimentFormatError(f"{label}: {section} {message}", path=label, key=f"environment.{key}")

    if not isinstance(table, Mapping):
        raise fail(f"must be a table, got {table!r}", "")
    for key in table:
        if key not in ENVIRONMENT_KEYS:
            raise fail(f"unknown key '{key}'; allowed: {', '.join(ENVIRONMENT_KEYS)}", key)
    name = table.get("name", default_name)
    if not isinstance(name, str) or not name.strip():
        raise fail(f"name must be a non-empty string, got {name!r}", "name")
    locked = table.get("locked", False)
    if not isinstance(locked, bool):
        raise fail(f"locked must be true or false, got {locked!r}", "locked")
    axes: list[tuple[str, list[float]]] = []
    for key in _NUMERIC:
        if key in table:
            axes.append((key, _values(table[key], lambda m, k=key: fail(f"{k} {m}", k))))
    grid_keys = [key for key, vals in axes if not _is_scalar(table[key])]
    points = math.prod(len(vals) for _, vals in axes)
    if points > limit_of("environments"):       # counted before any environment is built
        raise fail(f"grid of {' x '.join(str(len(v)) for _, v in axes if len(v) > 1)} = {points} environments, more "
                   f"than a set may have ({limit_of('environments')})", grid_keys[0] if grid_keys else "")
    for point in itertools.product(*(vals for _, vals in axes)):
        values = dict(zip((key for key, _ in axes), point), locked=locked)
        suffix = ",".join(f"{key}={values[key]:.4g}" for key in grid_keys)
        try:
            env, note = _build(values, link, "")
        except ParameterError as exc:
            raise fail(str(exc).removeprefix("[environment] "), exc.name or "") from None
        yield (f"{name}[{suffix}]" if suffix else name), env, note


def _is_scalar(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _values(value: Any, fail) -> list[float]:
    """A key's values: a number, a list, a ``{log|lin = [a, b], n = N}`` grid, or ``{nominal, rel}``."""
    if _is_scalar(value):
        return [_finite(value, fail)]
    if isinstance(value, list):
        if not value:
            raise fail("list is empty")
        if len(value) > limit_of("environments"):
            raise fail(f"list has {len(value)} values, more than a set may have ({limit_of('environments')})")
        return [_finite(v, fail) for v in value]
    if not isinstance(value, Mapping):
        raise fail(f"must be a number, a list, {{log = [a, b], n = N}}, {{lin = [a, b], n = N}} or "
                   f"{{nominal = x, rel = r}}, got {value!r}")
    keys = set(value)
    if keys == {"nominal", "rel"}:
        nominal, rel = _finite(value["nominal"], fail), _finite(value["rel"], fail)
        if not 0.0 <= rel < 1.0:
            raise fail(f"rel must be in [0, 1), got {rel!r}")
        return [nominal] if rel == 0.0 else [nominal * (1.0 - rel), nominal, nominal * (1.0 + rel)]
    if keys in ({"log", "n"}, {"lin", "n"}):
        kind = "log" if "log" in keys else "lin"
        ends, n = value[kind], value["n"]
        if not (isinstance(ends, list) and len(ends) == 2):
            raise fail(f"{kind} must be [first, last], got {ends!r}")
        a, b = (_finite(v, fail) for v in ends)
        top = limit_of("environments")
        if isinstance(n, bool) or not isinstance(n, int) or not 2 <= n <= top:
            raise fail(f"n must be an integer in [2, {top}] (the most environments of one set), got {n!r}")
        if kind == "log":
            if a <= 0.0 or b <= 0.0:
                raise fail(f"log grid ends must be > 0, got {ends!r}")
            return [float(v) for v in np.geomspace(a, b, n)]
        return [float(v) for v in np.linspace(a, b, n)]
    raise fail(f"table must be {{log = [a, b], n = N}}, {{lin = [a, b], n = N}} or "
               f"{{nominal = x, rel = r}}, got keys {sorted(keys)}")


def _finite(value: Any, fail) -> float:
    if not _is_scalar(value) or not math.isfinite(value):
        raise fail(f"must be a finite number, got {value!r}")
    return float(value)


# --- testbed --------------------------------------------------------------------------------


def testbed_of_environment_files(specs: Any) -> tuple[Testbed, str] | None:
    """The ``[testbed]`` of the environment files among ``specs`` (``--env FILE`` without ``--testbed``).

    Parameters
    ----------
    specs : str, path or sequence of them
        Environment specs as given (``FILE.toml``, ``FILE.toml#NAME``, presets, comma lists).

    Returns
    -------
    (Testbed, str) or None
        The testbed and its file; None when no environment file carries a ``[testbed]``.

    Raises
    ------
    ParameterError
        Two files carrying different testbeds.
    """
    found: tuple[Testbed, str] | None = None
    for spec in [specs] if isinstance(specs, (str, os.PathLike)) else (specs if isinstance(specs, (list, tuple)) else []):
        for part in str(spec).split(",") if isinstance(spec, (str, os.PathLike)) else ():
            path = Path(part.split("#", 1)[0].strip())
            doc = _read_toml(path) if path.suffix.lower() == ".toml" and path.is_file() else {}
            if "format" in doc or not isinstance(doc.get("testbed"), Mapping):
                continue     # not an environment file with a testbed (a scenario's goes with its environment)
            testbed = _testbed_table(doc["testbed"], str(path))
            if found is not None and found[0] != testbed:
                raise ParameterError(f"{found[1]} and {path} describe different testbeds: give --testbed",
                                     name="testbed", value=str(path))
            found = (testbed, str(path))
    return found


def resolve_testbed(spec: Any = None) -> Testbed:
    """Turn a description of the testbed into a :class:`~forecast_design.params.Testbed`.

    Parameters
    ----------
    spec : None, Testbed, Design, str or path
        None or ``"table1"``: the paper's Table 1; a Testbed (or a Design's testbed); inline
        values ``"k=40[,J_m=..][,d_m=..][,J_l=..,d_l=..]"`` (missing keys keep Table 1's); a TOML
        file with a ``[testbed]`` table (the same keys; missing ones keep Table 1's) or a run's or
        a scenario's TOML (its CSV is not read; the testbed carries its environment's link).
        ``J_l`` and ``d_l``, given together, are the SEA's link: the default of every environment
        used with this testbed that sets none (:func:`resolve_environments`, :class:`Design`).

    Returns
    -------
    Testbed
        J_m [kg m^2], d_m [N m s/rad], k [N m/rad], and the link J_l [kg m^2], d_l [N m s/rad]
        or None.

    Raises
    ------
    ParameterError
        Malformed inline value.
    ExperimentFormatError
        Malformed TOML file (one line naming the file and key).

    Warns
    -----
    ImplausibleInputWarning
        A given number outside what a benchtop SEA can be
        (:data:`~forecast_design.plausibility.BENCHTOP_SEA`), e.g. a value in the wrong unit.
    """
    if spec is None:
        return Testbed()
    if isinstance(spec, Testbed):
        return spec
    if isinstance(spec, Design):
        return spec.testbed
    if not isinstance(spec, (str, os.PathLike)):
        raise ParameterError(f"cannot read a testbed from {type(spec).__name__} {spec!r}; give a Testbed, "
                             f"inline k=..,J_m=..,d_m=.. values or a TOML file", name="testbed", value=spec)
    text = os.fspath(spec).strip()
    if text in ("table1", "nominal", "forecast"):
        return Testbed()
    if "=" in text and not text.lower().endswith(".toml"):
        where = f"testbed '{text}': "
        values: dict[str, float] = {}
        for item in (t.strip() for t in text.split(",") if t.strip()):
            key, sep, value = (s.strip() for s in item.partition("="))
            if not sep or key not in TESTBED_KEYS:
                raise ParameterError(f"{where}expected key=value with keys {', '.join(TESTBED_KEYS)}, "
                                     f"got {item!r}", name="testbed", value=text)
            if key in values:
                raise ParameterError(f"{where}key '{key}' given twice", name=key, value=text)
            try:
                values[key] = float(value)
            except ValueError:
                raise ParameterError(f"{where}{key} must be a number, got {value!r}", name=key,
                                     value=value) from None
        try:
            testbed = dataclasses.replace(Testbed(), **values)
        except ParameterError as exc:
            raise ParameterError(f"{where}{exc}", name=exc.name, value=exc.value) from None
        _warn_benchtop(testbed, f"testbed '{text}':")
        return testbed
    path = Path(text)
    label = str(path)
    if not path.is_file():
        raise ExperimentFormatError(f"{label}: testbed file not found", path=label)
    doc = _read_toml(path)
    if "format" in doc:
        return _formatted_design(doc, label)[0]
    table = doc.get("testbed")
    if table is None:
        raise ExperimentFormatError(f"{label}: no [testbed] table", path=label, key="testbed")
    if not isinstance(table, Mapping):
        raise ExperimentFormatError(f"{label}: [testbed] must be a table, got {table!r}", path=label,
                                    key="testbed")
    return _testbed_table(table, label)

"""rl-zoo-style hyperparameter files: ``env id -> settings``, falling back to ``default``.

The format is rl-baselines3-zoo's (``hyperparams/<algo>.yml``): top-level keys are environment ids
(plus an optional ``default``), each mapping to the settings of one run. A few keys are the zoo's
*special keys* (how to build the environment and how long to train); every other key goes straight to
the algorithm's constructor, after the zoo's pre-processing:

* ``learning_rate`` (and ``clip_range``, ``clip_range_vf``, and CMZDRIL's ``bc_learning_rate``) may be
  ``lin_<float>``: a schedule that decreases linearly from ``<float>`` to 0 over training, as in the zoo;
* ``train_freq: [1, "episode"]`` becomes a tuple;
* ``policy_kwargs`` / ``replay_buffer_kwargs`` / ``env_kwargs`` / ``normalize`` may be strings such as
  ``"dict(log_std_init=-3, net_arch=[400, 300], activation_fn=nn.ReLU)"``. The zoo ``eval``s them; we
  parse them with :mod:`ast` and accept only literals, lists/tuples/dicts, ``dict(...)`` with keyword
  arguments, and ``nn.<Name>`` / ``th.nn.<Name>`` / ``torch.nn.<Name>`` (torch.nn module classes) or
  ``th.optim.<Name>`` (optimizer classes). Anything else raises :class:`ValueError` naming the text.

A key written twice in one mapping (two ``n_epochs``, two ``per_method`` blocks) is refused, naming
the file, the key and its line (:class:`UniqueKeyLoader`): PyYAML would keep the last without a word.

The environment lookup follows the zoo, extended to module-prefixed ids: the exact id, then the id
without its ``module:`` prefix (``sb3_cmzdril:WaypointNav-v0`` -> ``WaypointNav-v0``), then
``default``; otherwise a :class:`KeyError`-free :class:`ValueError` lists the available keys.
"""
from __future__ import annotations

import ast
import copy
import dataclasses
import math
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import yaml

from sb3_cmzdril.errors import MissingFileError, UserError

#: Keys the zoo handles itself; everything else is an algorithm constructor argument.
SPECIAL_KEYS = (
    "n_timesteps",
    "policy",
    "n_envs",
    "normalize",
    "env_wrapper",
    "vec_env_wrapper",
    "callback",
    "policy_kwargs",
    "env_kwargs",
    "frame_stack",
)
#: Keys that may hold a zoo schedule string (``lin_<float>``).
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf", "bc_learning_rate")
#: Keys that may hold a python-expression string in the zoo (parsed safely here).
EXPRESSION_KEYS = ("policy_kwargs", "replay_buffer_kwargs", "env_kwargs", "normalize")

DEFAULT_KEY = "default"
#: Training episodes per trial when neither --n-demos nor the YAML says: the paper's MuJoCo setting.
FALLBACK_N_DEMOS = 1
#: The policy when the YAML names none.
FALLBACK_POLICY = "MlpPolicy"
#: An env entry's key for settings that only some methods take: ``{method: {key: value}}``, laid over
#: the entry for a run of that method (a grid can run each method at the setting it was measured best at).
PER_METHOD_KEY = "per_method"


class LinearSchedule:
    """The zoo's ``lin_<v>``: ``progress_remaining * initial_value`` (from ``v`` down to 0).

    A module-level class (not a closure) so models saved with it load anywhere.
    """

    def __init__(self, initial_value: float) -> None:
        self.initial_value = float(initial_value)

    def __call__(self, progress_remaining: float) -> float:
        return progress_remaining * self.initial_value

    def __repr__(self) -> str:
        return f"lin_{self.initial_value:g}"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, LinearSchedule) and other.initial_value == self.initial_value


def parse_schedule(value: Any, key: str = "learning_rate") -> Any:
    """``lin_<float>`` -> :class:`LinearSchedule`; numbers pass through; other strings -> ValueError."""
    if isinstance(value, str):
        kind, sep, number = value.partition("_")
        if kind == "lin" and sep:
            try:
                return LinearSchedule(float(number))
            except ValueError:
                pass
        raise UserError(
            f"invalid schedule for {key}: {value!r} (expected a number or 'lin_<float>', e.g. 'lin_7.3e-4')"
        )
    if isinstance(value, bool) or not isinstance(value, (int, float)) and not callable(value):
        raise UserError(f"invalid value for {key}: {value!r}")
    return value


# -- safe expression parsing ----------------------------------------------------------------------
_MODULE_ALIASES = {
    ("nn",): "nn",
    ("th", "nn"): "nn",
    ("torch", "nn"): "nn",
    ("optim",): "optim",
    ("th", "optim"): "optim",
    ("torch", "optim"): "optim",
}


def _attribute_chain(node: ast.AST) -> list | None:
    names = []
    while isinstance(node, ast.Attribute):
        names.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name):
        return None
    names.append(node.id)
    return names[::-1]


def _resolve_torch_class(chain: list) -> Any:
    import torch

    *module, name = chain
    kind = _MODULE_ALIASES.get(tuple(module))
    if kind is None or not name.isidentifier() or name.startswith("_"):
        return None
    obj = getattr(torch.nn if kind == "nn" else torch.optim, name, None)
    base = torch.nn.Module if kind == "nn" else torch.optim.Optimizer
    if isinstance(obj, type) and issubclass(obj, base):
        return obj
    return None


def safe_eval(text: str) -> Any:
    """Evaluate a zoo kwargs string without ``eval``.

    Accepted: numbers, strings, True/False/None, negative numbers, lists, tuples, dicts,
    ``dict(key=value, ...)``, and torch classes written ``nn.X``, ``th.nn.X``, ``torch.nn.X``
    (``nn.Module`` subclasses) or ``th.optim.X`` (optimizers). Raises ValueError otherwise.
    """
    if not isinstance(text, str):
        raise UserError(f"expected an expression string, got {type(text).__name__}")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as e:
        raise UserError(f"cannot parse {text!r}: {e.msg}") from e
    source = text.strip()

    def fail(node: ast.AST, why: str = "not allowed") -> UserError:
        segment = ast.get_source_segment(source, node) or ast.dump(node)
        return UserError(
            f"{why}: {segment!r} in {text!r} (only literals, lists, dicts, dict(...) and nn.<Name> are accepted)"
        )

    def conv(node: ast.AST) -> Any:
        if isinstance(node, ast.Constant):
            if isinstance(node.value, (int, float, str, bool, type(None))):
                return node.value
            raise fail(node)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
            value = conv(node.operand)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise fail(node)
            return -value if isinstance(node.op, ast.USub) else value
        if isinstance(node, ast.List):
            return [conv(e) for e in node.elts]
        if isinstance(node, ast.Tuple):
            return tuple(conv(e) for e in node.elts)
        if isinstance(node, ast.Dict):
            keys = [k for k in node.keys if k is not None]  # None stands for a '**' entry
            if len(keys) != len(node.keys):
                raise fail(node, "'**' unpacking is not allowed")
            return {conv(k): conv(v) for k, v in zip(keys, node.values, strict=True)}
        if isinstance(node, ast.Call):
            if isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
                if any(kw.arg is None for kw in node.keywords):
                    raise fail(node, "'**' unpacking is not allowed")
                return {kw.arg: conv(kw.value) for kw in node.keywords}
            raise fail(node, "function call not allowed")
        if isinstance(node, ast.Attribute):
            chain = _attribute_chain(node)
            cls = _resolve_torch_class(chain) if chain else None
            if cls is None:
                raise fail(node, "unknown or disallowed attribute")
            return cls
        raise fail(node)

    return conv(tree.body)


def parse_env_kwargs(text: str, option: str = "--env-kwargs") -> dict[str, Any]:
    """The keyword arguments of ``gym.make`` a command line gives as one expression
    (``"dict(continuous=True)"`` or ``"{'max_steps': 200}"``), read by :func:`safe_eval`."""
    kwargs = safe_eval(text)
    if not isinstance(kwargs, dict):
        raise UserError(f"{option} must be a dict, got {text!r}")
    return kwargs


# -- loading -------------------------------------------------------------------------------------
class UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader, except that a mapping naming a key twice is an error.

    PyYAML keeps the last value of a repeated key without a word: a second ``n_epochs`` or a second
    ``per_method`` block in an entry would silently replace the first. Keys that a merge (``<<: *base``)
    brings may be overridden, as YAML intends; only a key written twice in one mapping is refused, by
    a :class:`yaml.constructor.ConstructorError` whose ``problem`` names the key and both lines and
    whose ``problem_mark`` points at the second (:func:`load_yaml` makes one line of it).
    """

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        first_lines: dict[Any, int] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=deep)
            line = key_node.start_mark.line + 1
            try:
                first = first_lines.get(key)
            except TypeError:  # an unhashable key: SafeLoader's own construct_mapping refuses it
                continue
            if first is not None:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r} at line {line} (first at line {first})", key_node.start_mark
                )
            first_lines[key] = line
        return super().construct_mapping(node, deep=deep)


def load_yaml(text: str, what: str, loader: type[UniqueKeyLoader] = UniqueKeyLoader) -> Any:
    """``text`` read with ``loader`` (:class:`UniqueKeyLoader` or a subclass); a :class:`UserError` of one
    line naming ``what`` (e.g. ``"hyperparameter file hp.yml"``), the problem and its line otherwise."""
    try:
        return yaml.load(text, Loader=loader)  # a SafeLoader: builds plain data only
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        if e.problem is not None and e.problem.startswith("duplicate key"):
            raise UserError(f"{what}: {e.problem}; each key may appear once in a mapping") from None
        problem = " ".join(str(e.problem or e.context or "unreadable").split())
        raise UserError(f"{what} is not valid YAML: {problem}{where}") from None
    except yaml.YAMLError as e:
        raise UserError(f"{what} is not valid YAML: {' '.join(str(e).split())}") from None


@dataclasses.dataclass
class Hyperparams:
    """One entry of a zoo hyperparameter file, split into its parts.

    ``algo_kwargs`` go to the algorithm's constructor (``policy_kwargs`` is kept separate so callers
    can merge their own); :meth:`model_kwargs` gives both together. ``raw`` is the entry as written
    in the file (JSON-friendly; use it for metadata).
    """

    env_id: str
    key: str
    path: str | None
    raw: dict[str, Any]
    n_timesteps: int | None = None
    policy: str | None = None
    n_envs: int = 1
    policy_kwargs: dict[str, Any] = dataclasses.field(default_factory=dict)
    env_kwargs: dict[str, Any] = dataclasses.field(default_factory=dict)
    normalize: Any = None
    env_wrapper: Any = None
    vec_env_wrapper: Any = None
    callback: Any = None
    frame_stack: Any = None
    algo_kwargs: dict[str, Any] = dataclasses.field(default_factory=dict)
    #: The methods the entry's ``per_method`` block names (whichever one was resolved), for the
    #: caller that knows the method names to check them.
    per_method_names: tuple[str, ...] = ()

    def model_kwargs(self) -> dict[str, Any]:
        """Constructor kwargs: ``algo_kwargs`` plus ``policy_kwargs`` when there are any."""
        kwargs = dict(self.algo_kwargs)
        if self.policy_kwargs:
            kwargs["policy_kwargs"] = dict(self.policy_kwargs)
        return kwargs

    def check_supported(
        self,
        unsupported: Iterable[str] = ("normalize", "env_wrapper", "vec_env_wrapper", "callback", "frame_stack"),
        what: str = "this command",
    ) -> None:
        """Raise ValueError for special keys that are set but that the caller does not implement."""
        used = [k for k in unsupported if getattr(self, k) not in (None, False)]
        if used:
            raise UserError(
                f"hyperparameters {self.key!r} in {self.path} set {used}, which {what} does not support; "
                "remove them or use rl-zoo3 for this environment"
            )


# -- constructor arguments ---------------------------------------------------------------------------
#: Checks for the plain types that constructor annotations name; an annotation naming anything else
#: (``torch.device``, ``ActionNoise``, a class) is not checked here but by the constructor itself.
_TYPE_CHECKS: dict[str, Callable[[Any], bool]] = {
    "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "float": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
    "bool": lambda v: isinstance(v, bool),
    "str": lambda v: isinstance(v, str),
    "None": lambda v: v is None,
    "NoneType": lambda v: v is None,
    "Callable": callable,
    "Schedule": callable,
    "tuple": lambda v: isinstance(v, (tuple, list)),
    "Tuple": lambda v: isinstance(v, (tuple, list)),
    "Sequence": lambda v: isinstance(v, (tuple, list)),
    "list": lambda v: isinstance(v, (tuple, list)),
    "List": lambda v: isinstance(v, (tuple, list)),
    "dict": lambda v: isinstance(v, dict),
    "Dict": lambda v: isinstance(v, dict),
}
_TYPE_NAMES = {
    "Callable": "a schedule",
    "Schedule": "a schedule",
    "NoneType": "None",
    "Tuple": "tuple",
    "Sequence": "list",
    "List": "list",
    "Dict": "dict",
}


def _split_top_level(text: str, sep: str) -> list[str]:
    """``text`` split at ``sep`` outside brackets: ``"a[b, c], d"`` -> ``["a[b, c]", "d"]``."""
    parts, depth, start = [], 0, 0
    for i, ch in enumerate(text):
        depth += {"[": 1, "]": -1}.get(ch, 0)
        if ch == sep and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return [part.strip() for part in parts if part.strip()]


def annotation_alternatives(annotation: Any) -> list[str]:
    """The type names an annotation allows at its top level, for real and string annotations alike.

    ``int`` -> ``["int"]``; ``"Optional[Dict[str, Any]]"`` -> ``["Dict", "None"]``;
    ``float | Callable[[float], float]`` -> ``["float", "Callable"]``.
    """
    if isinstance(annotation, type):
        return [annotation.__name__]
    names: list[str] = []
    for part in _split_top_level(annotation if isinstance(annotation, str) else str(annotation), "|"):
        head, _, inner = part.partition("[")
        head = head.strip().rsplit(".", 1)[-1]
        inner = inner[:-1] if inner.endswith("]") else inner
        if head == "Optional":
            names += annotation_alternatives(inner) + ["None"]
        elif head == "Union":
            for alternative in _split_top_level(inner, ","):
                names += annotation_alternatives(alternative)
        else:
            names.append(head)
    return names


def check_constructor_kwargs(hp: Hyperparams, classes: Sequence[type]) -> None:
    """ValueError, naming the file and the key, for an ``algo_kwargs`` entry that no class in
    ``classes`` accepts or whose value has a type its annotation rules out.

    The zoo passes these straight to the constructor, where ``n_steps: "lots"`` fails deep inside
    SB3 with an unrelated message (or only once training has started); checked here, the mistake is
    reported before any file is written. The first class naming a parameter decides its type.
    """
    import inspect

    parameters: dict[str, inspect.Parameter] = {}
    for cls in classes:
        for name, parameter in inspect.signature(cls).parameters.items():
            if parameter.kind not in (parameter.VAR_KEYWORD, parameter.VAR_POSITIONAL):
                parameters.setdefault(name, parameter)
    for name in ("policy", "env", "_init_setup_model"):
        parameters.pop(name, None)
    where = f"hyperparameters {hp.key!r}" + (f" in {hp.path}" if hp.path else "")
    unknown = sorted(set(hp.algo_kwargs) - set(parameters))
    if unknown:
        raise UserError(f"{where}: {unknown} are not {'/'.join(c.__name__ for c in classes)} arguments")
    for name, value in hp.algo_kwargs.items():
        # YAML's .inf and .nan pass every range check written "not value > 0" or "value >= 0"; the
        # model would train on them, or fail only once files are written.
        if isinstance(value, float) and not math.isfinite(value):
            raise UserError(f"{where}: {name} must be finite, got {hp.raw.get(name, value)!r}")
        annotation = parameters[name].annotation
        if annotation is inspect.Parameter.empty:
            continue
        allowed = annotation_alternatives(annotation)
        if not all(a in _TYPE_CHECKS for a in allowed):
            continue
        if not any(_TYPE_CHECKS[a](value) for a in allowed):
            expected = " or ".join(dict.fromkeys(_TYPE_NAMES.get(a, a) for a in allowed))
            raise UserError(
                f"{where}: {name} must be {expected}, got {hp.raw.get(name, value)!r} ({type(value).__name__})"
            )


def _entry_key(available: Iterable[str], env_id: str) -> str | None:
    keys = list(available)
    if env_id in keys:
        return env_id
    if ":" in env_id:
        short = env_id.rsplit(":", 1)[1]
        if short in keys:
            return short
    if DEFAULT_KEY in keys:
        return DEFAULT_KEY
    return None


def split_hyperparams(entry: dict[str, Any], env_id: str = "", key: str = "", path: str | None = None) -> Hyperparams:
    """Split one zoo entry (a dict) into special keys and algorithm kwargs, with pre-processing."""
    if not isinstance(entry, dict):
        raise UserError(f"hyperparameters {key!r} in {path}: expected a mapping, got {type(entry).__name__}")
    raw = copy.deepcopy(entry)
    values = copy.deepcopy(entry)
    where = f"hyperparameters {key!r}" + (f" in {path}" if path else "")
    for k in EXPRESSION_KEYS:
        if isinstance(values.get(k), str):
            try:
                values[k] = safe_eval(values[k])
            except ValueError as e:
                raise UserError(f"{where}, {k}: {e}") from e
    for k in SCHEDULE_KEYS:
        if k in values:
            try:
                values[k] = parse_schedule(values[k], k)
            except ValueError as e:
                raise UserError(f"{where}: {e}") from e
    if isinstance(values.get("train_freq"), list):
        values["train_freq"] = tuple(values["train_freq"])
    hp = Hyperparams(env_id=env_id, key=key, path=path, raw=raw)
    if values.get("n_timesteps") is not None:
        try:
            hp.n_timesteps = int(float(values["n_timesteps"]))
        except (TypeError, ValueError) as e:
            raise UserError(f"{where}: n_timesteps must be a number, got {values['n_timesteps']!r}") from e
    policy = values.get("policy")
    if policy is not None:
        if not isinstance(policy, str) or "." in policy:
            raise UserError(f"{where}: policy must be a registered policy name such as 'MlpPolicy', got {policy!r}")
        hp.policy = policy
    n_envs = values.get("n_envs", 1)
    # A true integer: int() would make 2.5 two envs, "3" three and true one, each without a word.
    if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
        raise UserError(f"{where}: n_envs must be an integer >= 1, got {n_envs!r}")
    hp.n_envs = n_envs
    for k in ("policy_kwargs", "env_kwargs"):
        v = values.get(k)
        if v is None:
            v = {}
        if not isinstance(v, dict):
            raise UserError(f"{where}: {k} must be a dict, got {v!r}")
        setattr(hp, k, v)
    for k in ("normalize", "env_wrapper", "vec_env_wrapper", "callback", "frame_stack"):
        setattr(hp, k, values.get(k))
    hp.algo_kwargs = {k: v for k, v in values.items() if k not in SPECIAL_KEYS}
    return hp


def read_hyperparams_file(path: str | Path) -> dict[str, Any]:
    """The whole YAML file as a dict; clear errors for a missing or malformed file."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"hyperparameter file not found: {path}")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise UserError(f"hyperparameter file {path} is not UTF-8 text ({e.reason} at byte {e.start})") from None
    except OSError as e:
        raise UserError(f"hyperparameter file {path} cannot be read: {e.strerror or e}") from None
    data = load_yaml(text, f"hyperparameter file {path}")
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise UserError(f"hyperparameter file {path}: top level must map env ids to settings")
    return data


def resolve_per_method(entry: Any, method: str | None, where: str) -> tuple[Any, tuple[str, ...]]:
    """``entry`` without its :data:`PER_METHOD_KEY` block, with ``method``'s settings from it laid over
    the rest (none for ``method=None`` or a method the block does not name), and the names the block has.

    The entry returned is what a run of ``method`` uses (its :attr:`Hyperparams.raw`, which the run
    records), so a run's record never carries the settings of the other methods.
    """
    if not isinstance(entry, dict) or PER_METHOD_KEY not in entry:
        return entry, ()
    entry = dict(entry)
    block = entry.pop(PER_METHOD_KEY)
    if not isinstance(block, dict) or not all(isinstance(v, dict) for v in block.values()):
        raise UserError(f"{where}: {PER_METHOD_KEY} must map method names to settings, "
                        f"e.g. {{cmz: {{bc_epochs_per_update: 0}}}}, got {block!r}")
    for name, settings in block.items():
        if PER_METHOD_KEY in settings:
            raise UserError(f"{where}: {PER_METHOD_KEY}.{name} cannot hold another {PER_METHOD_KEY}")
    if method is not None and method in block:
        entry.update(copy.deepcopy(block[method]))
    return entry, tuple(map(str, block))


def load_hyperparams(path: str | Path, env_id: str, method: str | None = None) -> Hyperparams:
    """Load the entry for ``env_id`` from a zoo YAML file (exact id, id without ``module:``, ``default``),
    with ``method``'s settings from its ``per_method`` block (:func:`resolve_per_method`)."""
    data = read_hyperparams_file(path)
    key = _entry_key(data.keys(), env_id)
    if key is None:
        raise UserError(
            f"no hyperparameters for {env_id!r} in {path} and no {DEFAULT_KEY!r} entry; "
            f"available: {sorted(map(str, data.keys()))}"
        )
    entry, names = resolve_per_method(data[key] or {}, method, f"hyperparameters {key!r} in {path}")
    hp = split_hyperparams(entry, env_id=env_id, key=key, path=str(path))
    hp.per_method_names = names
    return hp


def default_hyperparams_path(algo: str) -> Path:
    """The shipped ``hyperparams/<algo>.yml``: the repository's file in a source checkout, the
    package's copy in a wheel install (:mod:`sb3_cmzdril.shipped`)."""
    from sb3_cmzdril.shipped import shipped_hyperparams

    return shipped_hyperparams(algo)

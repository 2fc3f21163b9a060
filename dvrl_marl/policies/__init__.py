"""Trained policies without torch: numpy inference for exported actors, and the policies shipped with the library.

An exported policy is a folder with ``policy.npz`` (weights ``W0, b0, W1, b1, ...``; no pickles) and
``policy.json`` (format, observation keys in the order the network reads them, layer activations, action bounds,
and the evaluation figures with the command that produced them).

>>> from dvrl_marl import policies
>>> policies.available()                       # doctest: +SKIP
['pick-lnd', 'pick-lnd', 'reach-lnd', 'reach-lnd', 'reach-suction-irrigation', 'reach-suction-irrigation']
>>> policy = policies.load("reach-lnd")     # doctest: +SKIP
>>> action = policy(observation)               # the env's observation dict in, an action array out

A multi-agent PPO policy also records the exploration noise it trained with (``policy.json``'s ``exploration``):
``policy.with_noise(seed)`` acts as it did in training (its mean action plus that noise, seeded), which is the
policy PPO optimised; some of these act better that way than by their mean (``baselines/README.md``). A policy may
also name observation ``features`` it computes from its observation before its first layer
(:mod:`dvrl_marl.suction_debris.features`), and ``switch_dimensions``: action dimensions it learnt as a switch (a jaw made
with ``jaw_command="switch"``), which it sends as -1 or 1 by their sign, so that a proportional jaw does the same.

A **pixel policy** (``policy.json``'s ``"image"``: :mod:`dvrl_marl.policies.image_encoder`) reads the endoscope's
image and the arm's own proprioception, nothing privileged: it is called on the observation of an env made with
``image_size`` (``policy.image_options`` says which), ``{"observation": ..., "image": ...}``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["load_seat", "NumpyPolicy", "NoisyPolicy", "available", "load", "shipped_dir", "POLICY_FORMAT"]

POLICY_FORMAT = "dvrl-marl-policy-v1"
_ACTIVATIONS = {
    "relu": lambda x: np.maximum(x, 0.0),
    "tanh": np.tanh,
    "identity": lambda x: x,
    "clip": lambda x: np.clip(x, -1.0, 1.0),  # a Gaussian policy's mean, clipped to the action box
}


def shipped_dir() -> Path:
    """Folder of the shipped policies (``baselines/policies`` in the repository, inside the wheel when installed)."""
    here = Path(__file__).resolve().parent
    for candidate in (here / "shipped", here.parents[1] / "baselines" / "policies"):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError("no shipped policies found (is the package installed?)")


class NumpyPolicy:
    """A multilayer perceptron actor evaluated with numpy: ``policy(observation) -> action``."""

    def __init__(self, weights: list[tuple[np.ndarray, np.ndarray]], spec: dict,
                 kernels: list[tuple[np.ndarray, np.ndarray]] | None = None,
                 readout: tuple[np.ndarray, np.ndarray] | None = None, keypoint_gains: np.ndarray | None = None):
        if spec.get("format") != POLICY_FORMAT:
            raise ValueError(f"not a {POLICY_FORMAT} policy (format {spec.get('format')!r})")
        activations = spec["activations"]
        if len(activations) != len(weights):
            raise ValueError(f"{len(weights)} layers but {len(activations)} activations")
        unknown = set(activations) - set(_ACTIVATIONS)
        if unknown:
            raise ValueError(f"unknown activation(s) {sorted(unknown)}")
        self.weights = weights
        self.spec = spec
        self.observation_keys = list(spec["observation_keys"])
        self._activations = [_ACTIVATIONS[a] for a in activations]
        self.action_low = np.asarray(spec["action_low"], dtype=np.float64)
        self.action_high = np.asarray(spec["action_high"], dtype=np.float64)
        self.switch_dimensions = list(spec.get("switch_dimensions", []))
        self.keep_clear = spec.get("keep_clear")
        self.felt_contact = None
        if spec.get("felt_contact") is not None:
            from dvrl_marl.policies.felt_contact import FeltContact

            if self.keep_clear is None:
                raise ValueError(f"policy {self.name!r}: felt_contact reads the tips and the arms' centres from "
                                 f"keep_clear, which it lacks")
            self.felt_contact = FeltContact(spec["felt_contact"], self.keep_clear)
        if spec.get("preset") is not None:  # the scene it learnt on, which the evaluations make
            from dvrl_marl.suction_debris.presets import PRESETS

            if spec["preset"] not in PRESETS:
                raise ValueError(f"policy {self.name!r}: preset {spec['preset']!r} is not a preset of the scene "
                                 f"({sorted(PRESETS)})")
        self.encoder = None
        if spec.get("image") is not None:
            from dvrl_marl.policies.image_encoder import ImageEncoder

            self.encoder = ImageEncoder(spec["image"], kernels or [], readout, keypoint_gains)
        self._feature_count = 0
        if "features" in spec:  # checked once here, not on every call (dvrl_marl.suction_debris.features)
            from dvrl_marl.suction_debris import features

            features.check_spec(spec["features"])
            self._feature_count = features.feature_count(spec["features"]["name"])
            reads = features.observation_width(spec["features"])
            width = (len(self.encoder.fills[0]) if self.encoder is not None and self.encoder.fills is not None
                     else None if self.encoder is not None else weights[0][0].shape[1] - self._feature_count)
            if reads is not None and width is not None and width != reads:
                raise ValueError(f"policy {self.name!r}: its features read an observation of {reads} values "
                                 f"({spec['features']['cavities']} cavities, {spec['features']['debris']} pins), its "
                                 f"network {width}")
        if self.keep_clear is not None:
            width = (len(self.encoder.fills[0]) if self.encoder is not None and self.encoder.fills is not None
                     else weights[0][0].shape[1] - self._feature_count)
            for name in ("own_tip", "other_tip"):
                if self.keep_clear[name][1] > width:
                    raise ValueError(f"policy {self.name!r}: keep_clear.{name} {self.keep_clear[name]} lies beyond "
                                     f"the {width} observation values it reads")

    @property
    def name(self) -> str:
        return self.spec.get("name", "policy")

    @property
    def image_options(self) -> dict | None:
        """The env options this policy's observation needs (``{"image_size": S}`` for a pixel policy, and
        ``"image_stereo": True`` for one that sees the stereo pair), else None."""
        if self.encoder is None:
            return None
        return {"image_size": self.encoder.size, **({"image_stereo": True} if self.encoder.stereo else {})}

    def _seen(self, observation) -> np.ndarray:
        """A pixel policy's input: the image encoded, then the arm's own proprioception."""
        keys = ("observation", *self.encoder.keys)
        if not isinstance(observation, dict) or any(key not in observation for key in keys):
            got = sorted(observation) if isinstance(observation, dict) else f"an array {np.shape(observation)}"
            made = ", ".join(f"{key}={value!r}" for key, value in self.image_options.items())
            raise ValueError(f"policy {self.name!r} sees the endoscope: it reads {set(keys)} from an env made with "
                             f"{made}, got {got}")
        images, vector = self.encoder.image(observation), np.asarray(observation["observation"])
        if self.encoder.fills is not None:
            wanted = f"{len(self.encoder.fills[0])} values"
            fits = vector.shape[-1:] == (len(self.encoder.fills[0]),)
        else:
            wanted = f"at least {self.encoder.proprioception.stop} values"
            fits = vector.ndim >= 1 and vector.shape[-1] >= self.encoder.proprioception.stop
        if not fits or vector.shape[:-1] != images.shape[:-3]:
            raise ValueError(f"policy {self.name!r} reads 'observation' as {wanted} per world, one per image, got "
                             f"shape {vector.shape} beside images {images.shape}")
        _check_finite(self.name, vector, "'observation'")
        return self.encoder.observation(images, vector)

    def features(self, observation) -> np.ndarray:
        return self._features(self._observed(observation))

    def _observed(self, observation):
        """What the network reads before its own features: the observation, or a pixel policy's encoding (its
        filled observation, with ``fills``)."""
        if self.encoder is not None:
            return self._seen(observation)
        return observation

    def _features(self, observation) -> np.ndarray:
        if self.encoder is not None and self.encoder.fills is None:
            return observation
        if isinstance(observation, dict):
            missing = [key for key in self.observation_keys if key not in observation]
            if missing:
                raise ValueError(f"policy {self.name!r} reads observation key(s) {missing}, absent from this env's "
                                 f"observation ({sorted(observation)})")
            try:
                parts = [np.asarray(observation[key], dtype=np.float64) for key in self.observation_keys]
                x = np.concatenate([p.reshape(p.shape[:-1] + (-1,)) if p.ndim > 1 else p for p in parts], axis=-1)
            except (TypeError, ValueError):  # (numpy's words for a part that is not numbers, or of another shape)
                shapes = {key: np.shape(observation[key]) for key in self.observation_keys}
                raise ValueError(f"policy {self.name!r} reads {self.observation_keys} as numbers, one row per world "
                                 f"each, got shapes {shapes}") from None
        else:
            try:
                x = np.asarray(observation, dtype=np.float64)
            except (TypeError, ValueError):
                raise ValueError(f"policy {self.name!r} reads an observation of numbers, got {observation!r:.80}") from None
        _check_finite(self.name, x, "observation")
        expected = self.weights[0][0].shape[1] - self._feature_count
        if self._feature_count and x.shape[-1] == expected:  # features it computes from its observation
            from dvrl_marl.suction_debris import features

            return features.apply(self.spec["features"], x)
        if self._feature_count and x.shape[-1] == expected + self._feature_count:
            return x  # an env made with observation_features appended them already
        if x.shape[-1] != expected:  # a policy meeting an env it was not made for (or a hand-edited file)
            raise ValueError(f"policy {self.name!r} ({self.spec.get('env_id', 'unknown env')}) reads {expected} "
                             f"observation features, got {x.shape[-1]}")
        return x

    def _network(self, x: np.ndarray, clip_last: bool) -> np.ndarray:
        last = len(self.weights) - 1
        for index, ((weight, bias), activation) in enumerate(zip(self.weights, self._activations)):
            x = x @ weight.T + bias
            if index < last or clip_last or self.spec["activations"][index] != "clip":
                x = activation(x)
        return x

    def reset(self, worlds=None) -> None:
        """Start the episodes of ``worlds`` (a mask or indices over the batch; None: all): a policy that keeps state
        per world (a pixel policy with ``image.fills.keep_lowest``) forgets it there; the others keep none."""
        if self.encoder is not None:
            self.encoder.reset(worlds)
        if self.felt_contact is not None:
            self.felt_contact.reset(worlds)

    def with_noise(self, seed=None) -> "NoisyPolicy":
        """This policy acting with its training's exploration noise (see :class:`NoisyPolicy`)."""
        return NoisyPolicy(self, seed)

    def __call__(self, observation) -> np.ndarray:
        observed = self._observed(observation)
        x = self._network(self._features(observed), clip_last=True)
        if self.switch_dimensions:  # (the switch's rule: open when positive, else closed)
            x[..., self.switch_dimensions] = np.where(x[..., self.switch_dimensions] > 0.0, 1.0, -1.0)
        # Networks act in [-1, 1]; map to the action space (identity for the dvrl-marl envs).
        action = self.action_low + (x + 1.0) * 0.5 * (self.action_high - self.action_low)
        if self.keep_clear is not None:
            action = self._kept_clear(action, observed)
        return action.astype(np.float32)

    def _kept_clear(self, action: np.ndarray, observed) -> np.ndarray:
        """``keep_clear``: the motion withheld where it would bring the instrument within ``keep`` of the other's
        and nearer (the scripted yielding suction's rule, on what this policy reads of the two tips)."""
        from dvrl_marl.suction_debris.instruments import keep_clear

        x = np.asarray(observed["observation"] if isinstance(observed, dict) else observed, dtype=np.float64)
        action = keep_clear(action, x, self.keep_clear)
        return action if self.felt_contact is None else self.felt_contact(action, x)


def _check_finite(name: str, values: np.ndarray, what: str) -> None:
    """A policy's input must be numbers: NaN or inf in, NaN actions out (said here, not after an episode of them)."""
    if not np.all(np.isfinite(values)):
        raise ValueError(f"policy {name!r}: its {what} holds NaN or inf")


class NoisyPolicy:
    """A policy acting as it did while it was trained: its mean action plus Gaussian noise of the standard deviation
    its ``policy.json`` records (``exploration.std``, one per action dimension; ``null`` for a dimension decided
    without noise, such as a switch tool), clipped to the action box; its own seeded stream, so an evaluation is
    reproducible. From :meth:`NumpyPolicy.with_noise`."""

    def __init__(self, policy: "NumpyPolicy", seed=None):
        exploration = policy.spec.get("exploration") or {}
        std = exploration.get("std")
        if std is None:
            raise ValueError(f"policy {policy.name!r} records no exploration noise (policy.json has no "
                             f"'exploration.std'); only its deterministic action exists")
        if len(std) != len(policy.action_low):
            raise ValueError(f"policy {policy.name!r}: exploration.std has {len(std)} values for "
                             f"{len(policy.action_low)} action dimensions")
        self.policy = policy
        self.std = np.array([0.0 if v is None else float(v) for v in std])
        if not np.all(np.isfinite(self.std)) or np.any(self.std < 0.0):
            raise ValueError(f"policy {policy.name!r}: exploration.std must be finite and >= 0, got {std!r}")
        self.rng = np.random.default_rng(seed)
        self.spec = policy.spec

    @property
    def name(self) -> str:
        return self.policy.name

    def reset(self, worlds=None) -> None:
        self.policy.reset(worlds)

    def __call__(self, observation) -> np.ndarray:
        # the Gaussian's mean before the clip (as in training: sample, then the env clips)
        policy = self.policy
        observed = policy._observed(observation)
        mean = policy._network(policy._features(observed), clip_last=False)
        action = np.clip(mean + self.std * self.rng.standard_normal(mean.shape), -1.0, 1.0)
        action = policy.action_low + (action + 1.0) * 0.5 * (policy.action_high - policy.action_low)
        if policy.keep_clear is not None:
            action = policy._kept_clear(action, observed)
        return action.astype(np.float32)


def available() -> list[str]:
    """Names of the shipped policies."""
    try:
        root = shipped_dir()
    except FileNotFoundError:
        return []
    return sorted(p.name for p in root.iterdir() if (p / "policy.json").is_file())


def load(name_or_path) -> NumpyPolicy:
    """A shipped policy by name, or an exported one from its folder (or its ``policy.json``)."""
    path = Path(name_or_path)
    if path.suffix == ".json":
        path = path.parent
    if not (path / "policy.json").is_file():
        if str(name_or_path) in available():
            path = shipped_dir() / str(name_or_path)
        else:
            raise FileNotFoundError(f"no policy {name_or_path!r}: not a folder with policy.json, nor one of "
                                    f"{available()}")
    spec, weights, kernels, readout, gains = _read_policy_folder(path)
    try:
        return NumpyPolicy(weights, spec, kernels, readout, gains)
    except ValueError as error:  # (every table checked at load: the file named)
        raise ValueError(f"{path / 'policy.json'}: {error}") from None


def load_seat(name_or_path, agent: str, who: str = "partner") -> NumpyPolicy:
    """:func:`load` for a seat of the collaborative scene: the policy must have been trained for ``agent``'s seat (a
    policy of the other seat, or a single-arm one, is an error naming what it is)."""
    policy = load(name_or_path)
    trained_for = policy.spec.get("agent")
    if trained_for is None:
        raise ValueError(f"{who} {name_or_path!r} is a single-arm policy ({policy.spec.get('env_id')}), not a seat "
                         f"of the collaborative scene; the {agent!r} seat needs a policy trained for it")
    if trained_for != agent:
        raise ValueError(f"{who} {name_or_path!r} was trained for the {trained_for!r} seat, not the {agent!r} seat")
    return policy


def _read_policy_folder(path: Path):
    """Read and check ``policy.json`` + ``policy.npz``: every failure names the file and the field."""
    from dvrl_marl.files import read_json, read_npz

    json_path, npz_path = path / "policy.json", path / "policy.npz"
    spec = read_json(json_path)
    from dvrl_marl.schemas import PolicyFile, validated

    checked = validated(PolicyFile, spec, str(json_path))
    if checked.format != POLICY_FORMAT:
        raise ValueError(f"{json_path}: field 'format' is {checked.format!r}, this library reads {POLICY_FORMAT!r}")
    activations, sizes = checked.activations, checked.layer_sizes
    for index, name in enumerate(activations):
        if name not in _ACTIVATIONS:
            raise ValueError(f"{json_path}: field 'activations[{index}]' is {name!r}; known: {sorted(_ACTIVATIONS)}")
    arrays = read_npz(npz_path)
    weights = []
    for index in range(len(activations)):
        layer = []
        for name, shape in ((f"W{index}", (sizes[index + 1], sizes[index])), (f"b{index}", (sizes[index + 1],))):
            if name not in arrays:
                raise ValueError(f"{npz_path}: missing array {name!r} (policy.json declares {len(activations)} layers)")
            array = arrays[name]
            if array.shape != shape:
                raise ValueError(f"{npz_path}: array {name!r} has shape {array.shape}, policy.json's layer_sizes "
                                 f"say {shape}")
            if not np.issubdtype(array.dtype, np.floating) or not np.all(np.isfinite(array)):
                raise ValueError(f"{npz_path}: array {name!r} must hold finite floats")
            layer.append(array)
        weights.append(tuple(layer))
    kernels, readout, gains = [], None, None
    if checked.image is not None:  # a pixel policy's convolutions and read-out (the schema checked their sizes)
        def image_array(name, shape):
            if name not in arrays:
                raise ValueError(f"{npz_path}: missing array {name!r} (policy.json's image declares it)")
            array = arrays[name]
            if array.shape != shape or not np.issubdtype(array.dtype, np.floating) or not np.all(np.isfinite(array)):
                raise ValueError(f"{npz_path}: array {name!r} must hold finite floats of shape {shape}, got "
                                 f"{array.dtype} {array.shape}")
            return array

        channels = 6 if checked.image.stereo else 3  # (the stereo pair's two images side by side)
        for index, (out, kernel, _) in enumerate(checked.image.convolutions):
            kernels.append((image_array(f"K{index}", (out, channels, kernel, kernel)),
                            image_array(f"k{index}", (out,))))
            channels = out
        if checked.image.readout is not None:
            size = (checked.image.readout, checked.image.readout_input_size())
            readout = (image_array("R", size), image_array("r", size[:1]))
        if checked.image.keypoints:  # the keypoints' softmax gains, one per channel of the last convolution
            gains = image_array("G", (checked.image.convolutions[-1][0],))
    return spec, weights, kernels, readout, gains

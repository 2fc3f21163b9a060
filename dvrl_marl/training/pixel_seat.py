"""A seat that works from the endoscope: distil a privileged seat into a policy that sees images (DAgger).

``dvrl-marl train baselines/configs/suction_pixels_dagger.toml`` trains the suction seat from what a robot has: the
endoscope's image (``image_size``, each world's look randomised, :mod:`dvrl_marl.envs.endoscope`) and the arm's own
proprioception (its tip and valve), never the blood volumes, pin positions or the other arm's tip that the
privileged seat (the teacher) reads.

1. **Collect** (:func:`collect`): worlds of the batched env beside the training partners; the teacher drives in
   round 0 (with DART noise on its motion, Laskey et al. 2017: it shows how to recover), the student in later
   rounds (DAgger, Ross, Gordon and Bagnell 2011; ``teacher_share``, DAgger's beta: the teacher still drives that
   share of the worlds, so that one student's stuck episodes do not make up the data); every ``record_every``-th
   step of each live world, the image, the proprioception and the teacher's action for that state join the data,
   with the privileged quantities the image shows (the other arm's tip, the blood left in each cavity) as
   auxiliary targets.
2. **Fit** (:func:`fit`): a small convolutional network ends in a linear **read-out** of a few estimates (the
   auxiliary targets, standardised, and one logit per cavity for "cleared": its blood under the task's threshold,
   the teacher's switch, a few pixels of blood at 64 px); a perceptron acts from those estimates and the
   proprioception alone (:class:`PixelActor`). The loss: the squared error of the motion and the logistic loss of
   the valve (a switch: open when its output is positive), plus the estimates' own errors (their squared error,
   and the logistic loss of "cleared"). The bottleneck is the point: the privileged seat acts from a handful of
   numbers (measured: its action moves with its own tip and tool and the blood left, hardly with anything else),
   and the image need only give those. Images are shifted by a few pixels at random (the endoscope's pose
   varies).
   By ``acts_by = "teacher"`` there is no perceptron to clone: the read-out estimates only the ``estimated`` slice
   of the teacher's observation (the blood left per cavity; squared errors weighted towards small values, where the
   teacher decides), and the exported policy is the teacher itself acting on an observation filled from the image
   (:mod:`dvrl_marl.policies.image_encoder`'s ``fills``): its own proprioception, the estimates raised by
   ``estimate_margin`` (an estimate too low makes it leave a cavity early), the scene's constants, zero for the
   rest (what it reads of those, the results page measures). The data then only has to teach perception, and
   DAgger's rounds bring the states where the student's estimates lead it.
3. **Validate** (:func:`validate`): the exported numpy policy, by its default call, beside the training partners on
   validation seeds (``teams.VALIDATION_SEED``); the best round is kept, a tie going to the later round.

The policy is exported numpy-only (:mod:`dvrl_marl.policies`, its ``image`` table) to ``<out>/policies/<name>``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, Field

from dvrl_marl.suction_debris.layout import MOVE, TOOL
from dvrl_marl.suction_debris.task import TASK
from dvrl_marl.schemas import (STRICT, Flag, Fraction, NonNegative, NonNegativeInt, Positive, PositiveInt, Text,
                               UnitInterval, validated)
from dvrl_marl.training import trainers

__all__ = ["PixelSeatConfig", "load_config", "PixelActor", "collect", "fit", "validate", "export", "train",
           "PIXEL_SEED"]

#: The worlds DAgger collects on are seeded from here: apart from every other trainer's and from the validation and
#: held-out ranges (teams.VALIDATION_SEED, teams.EVAL_SEED).
PIXEL_SEED = 200_000_000


class PixelSeatConfig(BaseModel):
    """``[run]`` of a pixel seat's configuration (every key optional but ``algorithm``)."""

    model_config = STRICT
    algorithm: Literal["pixel-dagger"]
    agent: Literal["suction", "grasper"] = "suction"
    teacher: Text = "marl-suction"
    partners: Annotated[list[Text], Field(min_length=1)] = ["scripted", "marl-grasper", "person-like"]
    image_size: Annotated[int, Field(ge=32, le=256)] = 64
    image_appearance: Literal["train", "none"] = "train"
    proprioception: Annotated[list[NonNegativeInt], Field(min_length=2, max_length=2)] = [0, 4]
    convolutions: list[Annotated[list[PositiveInt], Field(min_length=3, max_length=3)]] = [[16, 5, 2], [32, 3, 2],
                                                                                            [32, 3, 2]]
    hidden: list[PositiveInt] = [256, 256]
    rounds: PositiveInt = 4
    worlds: PositiveInt = 64
    record_every: PositiveInt = 2
    action_noise: NonNegative = 0.3
    teacher_share: Fraction = 0.0
    updates: PositiveInt = 1500
    first_updates: PositiveInt = 3000
    acts_by: Literal["perceptron", "teacher"] = "perceptron"
    estimated: Annotated[list[NonNegativeInt], Field(min_length=2, max_length=2)] = [7, 9]
    estimate_margin: NonNegative = 0.02
    # acts_by = "teacher": the policy keeps each cavity's blood estimate at the lowest of its episode
    # (image.fills.keep_lowest); estimate_margin is added to those estimates alone too
    keep_lowest: Flag = False
    # with keep_lowest: the blood estimates at this or more read as full (image.fills.full_above), as every cavity
    # the teacher met untouched read: a full cavity read a little low stalled it (docs/results.md)
    full_above: UnitInterval | None = None
    estimate_floor: Positive = 0.05
    # acts_by = "teacher": the estimates other than the blood (the other arm's tip) weigh their squared error in units
    # of their spread times this, beside the blood's weighted error (about 1e-5 once fitted: measured)
    other_estimate_weight: NonNegative = 1.0
    # acts_by = "teacher": the other arm's tip (where estimated) read as its offset from the arm's own tip, which the
    # seat knows exactly (image.fills.relative): an image moved or turned moves both tips alike
    other_tip_relative: Flag = False
    # acts_by = "teacher": the other arm's tip read from keypoints of the last convolution (a spatial softmax) and the
    # own proprioception alone, the blood from the flattened convolutions alone (image.keypoints): a linear read-out
    # of keypoints can take away a move of the view, which images moved in training (shift_px) show it
    keypoints: Flag = False
    # with keypoints: the other arm's tip reads the flattened convolutions too (the blood still not the keypoints), the
    # precision of the one beside what the other takes away of a moved view
    tip_reads_convolutions: Flag = False
    auxiliary: Annotated[list[NonNegativeInt], Field(min_length=2, max_length=2)] = [4, 9]
    auxiliary_weight: NonNegative = 1.0
    cleared_weight: NonNegative = 1.0
    batch_size: PositiveInt = 256
    learning_rate: Positive = 3e-4
    shift_px: Annotated[int, Field(ge=0, le=16)] = 3
    # each fitted image's channels times 1 +/- up to this (a gain per image and channel): what tells the blood from
    # the tissue must then be more than their absolute colours
    colour_jitter: Annotated[float, Field(ge=0.0, le=0.5)] = 0.0
    # false: each image's three gains divided by their mean, so that the jitter changes its colour, never its
    # brightness (which the held-out light's range holds)
    jitter_brightness: Flag = True
    # each fitted image times a gradient of light across it, 1 +/- up to this at its corners, any direction: the
    # light's direction changes what falls where, which a gain over the whole image never draws
    shading: Annotated[float, Field(ge=0.0, le=0.5)] = 0.0
    # each fitted image plus Gaussian noise of a spread drawn per image up to this (of 255), beyond the look's own:
    # the held-out looks' noise reaches twice the training range's
    image_noise: Annotated[float, Field(ge=0.0, le=32.0)] = 0.0
    # each fitted image's classes (tissue, blood, pin, instrument, background: the env's segmentation, recorded with
    # the frames) times their own gain per channel, 1 +/- up to this: the looks colour the tissue, the blood and the
    # instruments apart, which a gain over the whole image never draws
    class_jitter: Annotated[float, Field(ge=0.0, le=0.5)] = 0.0
    # per_image: each channel of each image at zero mean and unit spread; brightness: each image scaled to one mean
    # (an exposure: a gain over the whole image changes nothing the network reads)
    normalise: Literal["none", "per_image", "brightness"] = "none"
    # the student sees the stereo pair (the env's image_stereo): the left and right eyes' images as six channels,
    # each augmentation alike in both (the same shift, look, light; the noise each its own)
    stereo: Flag = False
    # frames where the other arm's tip is within near_mm of the arm's own are drawn into the fits' minibatches
    # (1 + near_weight) times as often as the others: where a seat must wait for the other instrument is a few frames
    # of an episode (about 14 % of them within 15 mm beside the surgeons in its way, fewer beside the others: measured)
    near_weight: NonNegative = 0.0
    near_mm: Positive = 15.0
    # acts_by = "teacher", the other arm's tip estimated: the seat withholds the moves that would bring its instrument
    # within this of the other's and nearer (the scripted yielding suction's rule, policy.json's keep_clear), on its
    # estimate of the other tip; the teacher drives by it too. A learned teacher waits from the states its own way
    # leads to, not from every state a student arrives in (docs/results.md)
    keep_clear_mm: Positive | None = None
    valve_weight: Positive = 1.0
    validation_episodes: PositiveInt = 48
    max_cycles: PositiveInt | None = None
    threads: PositiveInt | None = None


def load_config(path) -> tuple[str, PixelSeatConfig]:
    """``(name, config)`` of a TOML file whose ``[run]`` table is a :class:`PixelSeatConfig` (``[run] extends`` another
    file: :func:`dvrl_marl.files.read_extended_toml`)."""
    from dvrl_marl.files import read_extended_toml

    path = Path(path)
    table = read_extended_toml(path)
    unknown = set(table) - {"run"}
    if unknown:
        raise ValueError(f"{path}: unknown table(s) {sorted(unknown)}: a pixel seat's settings are all in [run]")
    config = validated(PixelSeatConfig, table.get("run", {}), str(path), table="run")
    if config.keep_lowest and config.acts_by != "teacher":
        raise ValueError(f"{path}: [run] keep_lowest is for acts_by = 'teacher' (the estimates filling its teacher's "
                         f"observation), got acts_by = {config.acts_by!r}")
    if config.full_above is not None and not config.keep_lowest:
        raise ValueError(f"{path}: [run] full_above reads the blood estimates kept at their lowest as full: it needs "
                         f"keep_lowest = true")
    if config.other_tip_relative and (config.acts_by != "teacher" or not _relative(config)):
        raise ValueError(f"{path}: [run] other_tip_relative reads the other arm's tip as an offset: it needs acts_by = "
                         f"'teacher' and the tip among the estimated indices, got acts_by = {config.acts_by!r}, "
                         f"estimated = {config.estimated}")
    if config.keep_clear_mm is not None and (config.acts_by != "teacher" or not _estimates_other_tip(config)):
        raise ValueError(f"{path}: [run] keep_clear_mm reads the other arm's tip from the seat's estimates: it needs "
                         f"acts_by = 'teacher' and the tip among the estimated indices, got acts_by = "
                         f"{config.acts_by!r}, estimated = {config.estimated}")
    if config.keypoints and config.acts_by != "teacher":
        raise ValueError(f"{path}: [run] keypoints reads the other arm's tip from keypoints and the blood from the "
                         f"flattened convolutions, the estimates of acts_by = 'teacher', got acts_by = "
                         f"{config.acts_by!r}")
    if config.tip_reads_convolutions and not config.keypoints:
        raise ValueError(f"{path}: [run] tip_reads_convolutions has the other arm's tip read the flattened "
                         f"convolutions beside the keypoints: it needs keypoints = true")
    return path.stem, config


def _torch():
    import torch

    return torch


def PixelActor(config: PixelSeatConfig, proprioception: int):
    """The student: convolutions (ReLU) over the image in [-0.5, 0.5], flattened, a linear read-out of the
    estimates; by ``acts_by = "perceptron"``, the estimates and the proprioception through ReLU layers to 4 outputs
    (the motion, the valve's logit); by ``"teacher"``, the read-out alone (the teacher acts on its estimates), with
    ``keypoints`` reading a spatial softmax's keypoints and the proprioception (``features(images, own)``) for the
    other arm's tip (and the flattened convolutions too by ``tip_reads_convolutions``), the flattened convolutions
    for the blood (a fixed mask over the read-out's weight)."""
    from dvrl_marl.policies.image_encoder import NORMALISE_FLOOR

    torch = _torch()
    nn = torch.nn

    class Actor(nn.Module):
        def __init__(self):
            super().__init__()
            layers, channels = [], _channels(config)
            for out, kernel, stride in config.convolutions:
                layers += [nn.Conv2d(channels, out, kernel, stride), nn.ReLU()]
                channels = out
            self.encoder = nn.Sequential(*layers)
            with torch.no_grad():
                size = self.encoder(torch.zeros(1, _channels(config), config.image_size,
                                                config.image_size)).flatten(1).shape[1]
            self.gains = None
            self.register_buffer("mask", None)
            if config.acts_by == "teacher":
                start, stop = config.estimated
                self.estimates = stop - start
                reads = size + (2 * channels + proprioception if config.keypoints else 0)
                self.readout, self.head = nn.Linear(reads, self.estimates), None
                if config.keypoints:  # the tip reads the keypoints and the proprioception, the blood the rest
                    self.gains = nn.Parameter(torch.ones(channels))
                    blood = torch.from_numpy(_blood_columns(config))[:, None]
                    flat = torch.arange(reads)[None, :] < size
                    tip_reads = ~flat | config.tip_reads_convolutions
                    self.mask = torch.where(blood, flat, tip_reads).float()
                return
            aux = config.auxiliary
            self.estimates = aux[1] - aux[0]
            self.readout = nn.Linear(size, self.estimates + len(_cleared_levels()))
            sizes = [self.readout.out_features + proprioception, *config.hidden, 4]
            head = []
            for index in range(len(sizes) - 1):
                head.append(nn.Linear(sizes[index], sizes[index + 1]))
                if index < len(sizes) - 2:
                    head.append(nn.ReLU())
            self.head = nn.Sequential(*head)

        def features(self, images, own=None):
            x = images.permute(0, 3, 1, 2).float() / 255.0
            if config.normalise == "per_image":  # as the numpy encoder does (its docstring)
                x = (x - x.mean(dim=(2, 3), keepdim=True)) / (x.std(dim=(2, 3), keepdim=True, correction=0)
                                                              + NORMALISE_FLOOR)
            elif config.normalise == "brightness":
                x = x * (0.5 / (x.mean(dim=(1, 2, 3), keepdim=True) + NORMALISE_FLOOR)) - 0.5
            else:
                x = x - 0.5
            x = self.encoder(x)
            if self.gains is None:
                return self.readout(x.flatten(1))
            # a spatial softmax per channel (as the numpy encoder's keypoints)
            logits = (x * self.gains[:, None, None]).flatten(2)
            weights = torch.softmax(logits, dim=2).view_as(x)
            columns = (weights.sum(2) * torch.linspace(-1.0, 1.0, x.shape[3])).sum(2)
            rows = (weights.sum(3) * torch.linspace(-1.0, 1.0, x.shape[2])).sum(2)
            inputs = torch.cat([x.flatten(1), columns, rows, own], dim=1)
            return torch.nn.functional.linear(inputs, self.readout.weight * self.mask, self.readout.bias)

        def readout_weight(self):
            """The read-out's weight as the numpy encoder reads it (what the mask keeps)."""
            weight = self.readout.weight.detach()
            return (weight if self.mask is None else weight * self.mask).numpy().astype(np.float32)

        def forward(self, images, own):  # images: (B, S, S, 3 or 6) uint8
            return self.head(torch.cat([self.features(images, own), own], dim=1))

    return Actor()


def _observation_keys(config: PixelSeatConfig) -> list[str]:
    """The observation's keys the exported policy reads."""
    return ["observation", "image", *(["image_right"] if config.stereo else [])]


def _channels(config: PixelSeatConfig) -> int:
    """The student's image channels: RGB, or the stereo pair's two side by side."""
    return 6 if config.stereo else 3


def _cleared_levels() -> list[tuple[int, float]]:
    """``(observation index, level)`` of each cavity's blood fraction at the task's "cleared" threshold."""
    from dvrl_marl.training.clone import cleared_features

    return cleared_features()


def _other(config: PixelSeatConfig) -> str:
    return "grasper" if config.agent == "suction" else "suction"


def _partner(config: PixelSeatConfig, noise_from: int | None = None):
    """The training partners in the other seat (one, or a share of the worlds each)."""
    from dvrl_marl.training import teams

    names = config.partners if len(config.partners) > 1 else config.partners[0]
    return teams.partner(names, _other(config), noise_from=noise_from)


def _env(config: PixelSeatConfig, worlds: int):
    from dvrl_marl.envs import suction_debris

    options = {} if config.max_cycles is None else {"max_cycles": config.max_cycles}
    return suction_debris.batched_env(num_envs=worlds, autoreset_mode="disabled", image_size=config.image_size,
                                         image_stereo=config.stereo,
                                         image_appearance=None if config.image_appearance == "none"
                                         else config.image_appearance, **options)


def _scene():
    """The scene's layout, observation layout and workspace range (the env's; one world reads them in
    milliseconds)."""
    from dvrl_marl.envs import suction_debris

    env = suction_debris.batched_env(num_envs=1)
    facts = env.layout(), env.observation_layout, env.workspace_range
    env.close()
    return facts


def _estimates_other_tip(config: PixelSeatConfig) -> bool:
    """Whether the seat's estimates hold all of the other arm's tip."""
    tip = _scene()[1]["other_tip"]
    return config.estimated[0] <= tip.start and tip.stop <= config.estimated[1]


def _keep_clear_table(config: PixelSeatConfig) -> dict | None:
    """The seat's ``keep_clear`` table (``keep_clear_mm``: the yielding suction's rule for ``config.agent``), or
    None."""
    from dvrl_marl.suction_debris.scripted_team import keep_clear_rule

    if config.keep_clear_mm is None:
        return None
    return keep_clear_rule(*_scene(), config.agent, config.keep_clear_mm)


def _relative(config: PixelSeatConfig) -> list[list[int]]:
    """``image.fills.relative``'s pairs ``[estimated, own]``: each estimated coordinate of the other arm's tip and the
    own tip's same coordinate (none unless ``other_tip_relative``)."""
    if not config.other_tip_relative:
        return []
    layout = _scene()[1]
    other, own = (range(layout[name].start, layout[name].stop) for name in ("other_tip", "own_tip"))
    estimated = range(*config.estimated)
    return [[index, own_index] for index, own_index in zip(other, own) if index in estimated]


def collect(config: PixelSeatConfig, student, seed: int, noise_seed: int) -> dict:
    """One episode in each of ``config.worlds`` worlds (seeded ``seed``, ``seed + 1``...): the student drives
    (the teacher with DART noise when ``student`` is None, and in the first ``teacher_share`` of the worlds), the
    teacher labels. Returns the recorded images ``(M, S, S, 3)``, proprioception ``(M, p)``, labels ``(M, 4)``,
    auxiliary targets ``(M, a)`` (the estimates, by ``acts_by = "teacher"``), "cleared" per cavity ``(M, C)``, how far
    apart the two arms' tips are ``(M,)`` mm, the episodes' success rate and the observation's constants (NaN where a
    value varied)."""
    from dvrl_marl.suction_debris.instruments import keep_clear
    from dvrl_marl.training import teams

    agent, other = config.agent, _other(config)
    env = _env(config, config.worlds)
    teacher = teams.seat(config.teacher, agent)
    rule = _keep_clear_table(config)
    partner = _partner(config, noise_from=seed)
    rng = np.random.default_rng(noise_seed)
    taught = np.arange(config.worlds) < (config.worlds if student is None else
                                         round(config.teacher_share * config.worlds))
    own = slice(*config.proprioception)
    observations, _ = env.reset(seed=seed)
    if hasattr(student, "reset"):  # (its episodes start here: a student keeping its lowest estimates forgets them)
        student.reset()
    done = np.zeros(config.worlds, dtype=bool)
    success = np.zeros(config.worlds, dtype=bool)
    images, proprioception, labels, targets, cleared, segments, apart = [], [], [], [], [], [], []
    own_tip, other_tip = env.observation_layout["own_tip"], env.observation_layout["other_tip"]
    aux = slice(*(config.estimated if config.acts_by == "teacher" else config.auxiliary))
    # targets read as offsets (other_tip_relative): columns of the targets, and the observation's indices subtracted
    relative = np.array([[index - aux.start, own_index] for index, own_index in _relative(config)], dtype=np.int64)
    low = high = observations[agent]["observation"][0]
    cleared_at = _cleared_levels()
    step = 0
    while not done.all():
        seen = observations[agent]
        label = np.asarray(teacher(seen["observation"]), dtype=np.float32)
        action = label.copy()
        action[:, MOVE] = np.clip(action[:, MOVE] + config.action_noise * rng.standard_normal((len(action), 3)),
                                -1.0, 1.0)
        if rule is not None:  # the teacher drives by the seat's rule too (on the truth: it reads the other tip)
            action = keep_clear(action, seen["observation"], rule)
        if not taught.all():
            action[~taught] = np.asarray(student({key: value[~taught] for key, value in seen.items()}),
                                         dtype=np.float32)
        if step % config.record_every == 0:
            live = ~done
            images.append(np.concatenate([seen["image"], seen["image_right"]], axis=-1)[live] if config.stereo
                          else seen["image"][live].copy())
            if config.class_jitter > 0:  # the classes the fit colours apart, drawn for the recorded steps alone
                eyes = ("segmentation", "segmentation_right") if config.stereo else ("segmentation",)
                drawn = env.images(parts=eyes)
                segments.append(np.stack([drawn[eye][live] for eye in eyes], axis=-1) if config.stereo
                                else drawn["segmentation"][live])
            proprioception.append(seen["observation"][live, own].astype(np.float32))
            labels.append(label[live])
            target = seen["observation"][live, aux].astype(np.float64)
            if len(relative):
                target[:, relative[:, 0]] -= seen["observation"][live][:, relative[:, 1]]
            targets.append(target.astype(np.float32))
            cleared.append(np.stack([seen["observation"][live, index] < level for index, level in cleared_at], 1))
            tips = seen["observation"][live]
            apart.append((1000.0 * env.workspace_range
                          * np.linalg.norm(tips[:, own_tip] - tips[:, other_tip], axis=1)).astype(np.float32))
            low = np.minimum(low, seen["observation"][live].min(0))
            high = np.maximum(high, seen["observation"][live].max(0))
        observations, _, terminations, truncations, infos = env.step(
            {agent: action, other: np.asarray(partner(observations[other]["observation"]))})
        success |= ~done & infos[agent]["is_success"]
        done |= terminations[agent] | truncations[agent]
        step += 1
    env.close()
    return {"images": np.concatenate(images), "proprioception": np.concatenate(proprioception),
            "labels": np.concatenate(labels), "targets": np.concatenate(targets),
            "cleared": np.concatenate(cleared).astype(np.float32), "tips_apart_mm": np.concatenate(apart),
            "success_rate": float(success.mean()), "steps": step,
            "constants": np.where(low == high, low, np.nan),
            **({"segmentation": np.concatenate(segments)} if segments else {})}


def _shifted(torch, images, shift: int, generator):
    """Each image moved by up to ``shift`` px along each axis (edges repeated): the endoscope's pose varies."""
    if shift == 0:
        return images
    count, size = images.shape[0], images.shape[1]
    padded = torch.nn.functional.pad(images.permute(0, 3, 1, 2).float(), (shift,) * 4, mode="replicate")
    offsets = torch.randint(0, 2 * shift + 1, (count, 2), generator=generator)
    rows = offsets[:, :1] + torch.arange(size)
    columns = offsets[:, 1:] + torch.arange(size)
    # (count, size, size, channels): picked pixel by pixel from each padded image
    return padded[torch.arange(count)[:, None, None], :, rows[:, :, None], columns[:, None, :]]


def _jittered(torch, images, jitter: float, generator, brightness: bool = True):
    """Each image's channels times their own gain in 1 +/- ``jitter`` (pixel values kept in 0..255); without
    ``brightness``, the gains divided by their mean (the colour changes, the brightness does not)."""
    if jitter == 0.0:
        return images
    gains = 1.0 + jitter * (2.0 * torch.rand((images.shape[0], 1, 1, 3), generator=generator) - 1.0)
    if not brightness:
        gains = gains / gains.mean(dim=3, keepdim=True)
    gains = gains.repeat(1, 1, 1, images.shape[3] // 3)  # (the stereo pair: both eyes alike)
    return (images.float() * gains).clamp(0.0, 255.0)


def _shaded(torch, images, shading: float, generator):
    """Each image times a plane of light, ``1 + a (x cos t + y sin t) / (|cos t| + |sin t|)`` with x and y from -1 to
    1 across it: ``a`` uniform in +/- ``shading`` (the gain at the farthest corners), ``t`` any direction (pixel
    values kept in 0..255)."""
    if shading == 0.0:
        return images
    count, size = images.shape[0], images.shape[1]
    strength = shading * (2.0 * torch.rand((count, 1, 1), generator=generator) - 1.0)
    angle = 2.0 * np.pi * torch.rand((count, 1, 1), generator=generator)
    across = torch.linspace(-1.0, 1.0, size)
    cos, sin = torch.cos(angle), torch.sin(angle)
    field = 1.0 + strength * (across[None, None, :] * cos + across[None, :, None] * sin) / (cos.abs() + sin.abs())
    return (images.float() * field[..., None]).clamp(0.0, 255.0)


def _class_jittered(torch, images, segmentation, jitter: float, generator):
    """Each image's classes (``segmentation``'s indices) times their own gain per channel in 1 +/- ``jitter`` (pixel
    values kept in 0..255)."""
    if jitter == 0.0:
        return images
    from dvrl_marl.envs.endoscope import SEGMENT_CLASSES

    count = images.shape[0]
    gains = 1.0 + jitter * (2.0 * torch.rand((count, len(SEGMENT_CLASSES), 3), generator=generator) - 1.0)
    # the stereo pair: each eye's classes (segmentation (count, S, S, 2)) in the same gains
    eyes = segmentation.unsqueeze(-1) if segmentation.dim() == 3 else segmentation
    per_pixel = torch.cat([gains[torch.arange(count)[:, None, None], eyes[..., eye].long()]
                           for eye in range(eyes.shape[-1])], dim=-1)  # (count, S, S, channels)
    return (images.float() * per_pixel).clamp(0.0, 255.0)


def _noised(torch, images, noise: float, generator):
    """Each image plus Gaussian noise whose standard deviation is drawn per image, uniform in [0, ``noise``] (pixel
    values kept in 0..255)."""
    if noise == 0.0:
        return images
    spread = noise * torch.rand((images.shape[0], 1, 1, 1), generator=generator)
    return (images.float() + spread * torch.randn(images.shape, generator=generator)).clamp(0.0, 255.0)


def fit(model, data: dict, config: PixelSeatConfig, updates: int, seed: int) -> float:
    """``updates`` steps of Adam on minibatches drawn from ``data`` (images, proprioception, labels, targets);
    returns the mean loss of the last tenth of them."""
    torch = _torch()
    generator = torch.Generator().manual_seed(seed)
    optimiser = getattr(model, "_optimiser", None)
    if optimiser is None:  # one optimiser across rounds: its moments carry on as the data grows
        optimiser = model._optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    images = torch.from_numpy(data["images"])
    if config.class_jitter > 0 and "segmentation" not in data:
        raise ValueError("fit: class_jitter needs the frames' segmentation (collect with the same configuration)")
    segmentation = torch.from_numpy(data["segmentation"]) if config.class_jitter > 0 else None
    chances = draw_chances(data, config)
    own = torch.from_numpy(data["proprioception"])
    labels = torch.from_numpy(data["labels"])
    targets = torch.from_numpy(data["targets"])
    functional = torch.nn.functional
    if config.acts_by == "teacher":  # the estimates alone: the teacher acts on them
        blood = torch.from_numpy(_blood_columns(config))
        # a cavity's blood: errors weigh more where it is small (the teacher's switch, a cavity near empty); any
        # other estimate (the other arm's tip): its squared error in units of its spread
        weights = 1.0 / (targets.abs() + config.estimate_floor) ** 2
        weights = torch.where(blood, weights / weights[:, blood].mean(),
                              config.other_estimate_weight / targets.var(0).clamp_min(1e-6))

        def batch_loss(batch, features):
            return (weights[batch] * (features - targets[batch]) ** 2).mean()
    else:
        if not hasattr(model, "_target_scale"):  # each estimate at one scale, fixed by the first round's data
            model._target_scale = (targets.mean(0), targets.std(0).clamp_min(1e-6))
        targets = (targets - model._target_scale[0]) / model._target_scale[1]
        cleared = torch.from_numpy(data["cleared"])
        opened = (labels[:, TOOL] > 0).float()
        estimates = model.estimates

        def batch_loss(batch, features):
            output = model.head(torch.cat([features, own[batch]], dim=1))
            return (functional.mse_loss(output[:, MOVE], labels[batch, MOVE])
                    + config.valve_weight * functional.binary_cross_entropy_with_logits(output[:, TOOL], opened[batch])
                    + config.auxiliary_weight * functional.mse_loss(features[:, :estimates], targets[batch])
                    + config.cleared_weight * functional.binary_cross_entropy_with_logits(features[:, estimates:],
                                                                                          cleared[batch]))
    model.train()
    losses = []
    for _ in range(updates):
        batch = (torch.randint(0, len(targets), (config.batch_size,), generator=generator) if chances is None else
                 torch.multinomial(chances, config.batch_size, replacement=True, generator=generator))
        seen = images[batch] if segmentation is None else _class_jittered(torch, images[batch], segmentation[batch],
                                                                          config.class_jitter, generator)
        seen = _jittered(torch, _shifted(torch, seen, config.shift_px, generator), config.colour_jitter,
                         generator, config.jitter_brightness)
        seen = _noised(torch, _shaded(torch, seen, config.shading, generator), config.image_noise, generator)
        loss = batch_loss(batch, model.features(seen, own[batch]))
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(loss.item())
    model.eval()
    return float(np.mean(losses[-max(1, updates // 10):]))


def draw_chances(data: dict, config: PixelSeatConfig):
    """Each frame's relative chance of a minibatch's draw in :func:`fit`: ``1 + near_weight`` where the two tips are
    within ``near_mm``, 1 elsewhere (a float64 tensor); None without ``near_weight`` (every frame alike, drawn
    uniformly)."""
    if config.near_weight == 0:
        return None
    if "tips_apart_mm" not in data:
        raise ValueError("fit: near_weight needs the frames' tips_apart_mm (collect with this version)")
    return 1.0 + config.near_weight * _torch().from_numpy(data["tips_apart_mm"] < config.near_mm).double()


def estimate_errors(model, data: dict, small: float = 0.15, blood: np.ndarray | None = None,
                    near_mm: float = 15.0) -> dict:
    """How the read-out's estimates of the blood left miss ``data``'s targets (frames it has not fitted yet, to be
    fair): the mean absolute error, and where a target is under ``small`` (a cavity near empty) the mean error, the
    mean absolute error and the error's 1st and 99th percentiles (an estimate below the truth makes the teacher leave
    too early, one far above keeps it in an empty cavity). ``blood`` marks the targets' columns that are blood (None:
    all); the others' mean absolute error is ``other_mean_absolute``, and ``other_near_mean_absolute`` on the frames
    whose tips are within ``near_mm`` of each other (where the seat must wait for the other instrument)."""
    torch = _torch()
    chunks = max(1, len(data["images"]) // 1024)
    with torch.no_grad():
        estimates = np.concatenate([model.features(torch.from_numpy(images), torch.from_numpy(own)).numpy()
                                    for images, own in zip(np.array_split(data["images"], chunks),
                                                           np.array_split(data["proprioception"], chunks))])
    errors = estimates[:, :data["targets"].shape[1]] - data["targets"]
    blood = np.ones(errors.shape[1], dtype=bool) if blood is None else blood
    error, near = errors[:, blood], data["targets"][:, blood] < small
    other = ({"other_mean_absolute": round(float(np.abs(errors[:, ~blood]).mean()), 4)} if not blood.all() else {})
    close = data["tips_apart_mm"] < near_mm if "tips_apart_mm" in data else np.zeros(len(errors), dtype=bool)
    if other and close.any():
        other["other_near_mean_absolute"] = round(float(np.abs(errors[close][:, ~blood]).mean()), 4)
    if not near.any():
        return {"mean_absolute": round(float(np.abs(error).mean()), 4), "small_mean": None,
                "small_mean_absolute": None, "small_first_percentile": None, "small_99th_percentile": None, **other}
    return {"mean_absolute": round(float(np.abs(error).mean()), 4), "small_mean": round(float(error[near].mean()), 4),
            "small_mean_absolute": round(float(np.abs(error[near]).mean()), 4),
            "small_first_percentile": round(float(np.percentile(error[near], 1)), 4),
            "small_99th_percentile": round(float(np.percentile(error[near], 99)), 4), **other}


def _blood_columns(config: PixelSeatConfig) -> np.ndarray:
    """Which of the ``estimated`` slice's columns are a cavity's blood left (the others: the other arm's tip...)."""
    cavities = {index for index, _ in _cleared_levels()}
    return np.array([index in cavities for index in range(*config.estimated)])


def export(model, config: PixelSeatConfig, directory, name: str, metadata: dict,
           constants: np.ndarray | None = None) -> Path:
    """The student as a numpy policy folder (:mod:`dvrl_marl.policies`, with its ``image`` table). By ``acts_by =
    "teacher"``: the teacher's own layers and features, acting on an observation filled from ``constants`` (the
    observation's values that never varied, NaN elsewhere: read as zero, which a hidden pin's position reads too),
    the proprioception and the estimates, each raised by ``estimate_margin`` (the teacher leaves a cavity too early
    on an estimate too low, never on one too high)."""
    from dvrl_marl.training.export import write_policy

    kernels = [(layer.weight.detach().numpy().astype(np.float32), layer.bias.detach().numpy().astype(np.float32))
               for layer in model.encoder if hasattr(layer, "weight")]
    if config.acts_by == "teacher":
        from dvrl_marl import policies

        teacher = policies.load_seat(config.teacher, config.agent, who="teacher")
        if constants is None:
            raise ValueError("export: acts_by = 'teacher' needs the observation's constants to fill")
        start, stop = config.estimated
        template = np.where(np.isnan(constants), 0.0, constants)
        template[start:stop] = 0.0
        template[slice(*config.proprioception)] = 0.0
        blood = _blood_columns(config)
        estimated = list(range(start, stop))
        image = {"key": "image", "size": config.image_size, "proprioception": list(config.proprioception),
                 "convolutions": [list(layer) for layer in config.convolutions], "readout": stop - start,
                 "normalise": config.normalise, "keypoints": config.keypoints, "stereo": config.stereo,
                 "fills": {"template": [float(value) for value in template], "estimates_at": estimated,
                           "keep_lowest": [index for index, kept in zip(estimated, blood) if kept and
                                           config.keep_lowest], "relative": _relative(config),
                           "full_above": config.full_above}}
        # the margin and the lowest kept are the blood's: a cavity only empties, and an estimate too low ends it
        readout = (model.readout_weight(), model.readout.bias.detach().numpy().astype(np.float32)
                   + np.float32(config.estimate_margin) * blood.astype(np.float32))
        gains = {} if model.gains is None else {"keypoint_gains": model.gains.detach().numpy().astype(np.float32)}
        layers = [(weight, bias, activation) for (weight, bias), activation
                  in zip(teacher.weights, teacher.spec["activations"])]
        extra = {"features": teacher.spec["features"]} if teacher.spec.get("features") else {}
        if config.keep_clear_mm is not None:
            extra["keep_clear"] = _keep_clear_table(config)
        return write_policy(directory, layers, name=name, env_id=TASK,
                            algorithm=f"DAgger (pixels: estimates for {teacher.name})",
                            observation_keys=_observation_keys(config), action_low=teacher.action_low.tolist(),
                            action_high=teacher.action_high.tolist(), kernels=kernels, readout=readout, image=image,
                            agent=config.agent, switch_dimensions=teacher.switch_dimensions, **gains, **extra,
                            **metadata)
    linear = [layer for layer in model.head if hasattr(layer, "weight")]
    layers = [(layer.weight.detach().numpy().astype(np.float32), layer.bias.detach().numpy().astype(np.float32),
               "clip" if index == len(linear) - 1 else "relu") for index, layer in enumerate(linear)]
    image = {"key": "image", "size": config.image_size, "proprioception": list(config.proprioception),
             "convolutions": [list(layer) for layer in config.convolutions],
             "readout": model.readout.out_features, "normalise": config.normalise, "stereo": config.stereo}
    readout = (model.readout.weight.detach().numpy().astype(np.float32),
               model.readout.bias.detach().numpy().astype(np.float32))
    return write_policy(directory, layers, name=name, env_id=TASK, algorithm="DAgger (pixels)",
                        observation_keys=_observation_keys(config), action_low=[-1.0] * 4, action_high=[1.0] * 4,
                        kernels=kernels, readout=readout, image=image, agent=config.agent, switch_dimensions=[3],
                        **metadata)


def validate(policy, config: PixelSeatConfig) -> dict:
    """The policy by its default call beside the training partners, on validation seeds."""
    from dvrl_marl.training import teams

    other = _other(config)
    partner = _partner(config)
    options = {} if config.max_cycles is None else {"max_cycles": config.max_cycles}
    if config.image_appearance != "none":
        options["image_appearance"] = config.image_appearance
    result = teams.evaluate_team_batched({config.agent: policy, other: partner}, config.validation_episodes,
                                         seed=teams.VALIDATION_SEED, **options)
    return {k: result[k] for k in ("success_rate", "mean_contact_steps", "median_steps_to_completion")}


def train(name: str, config: PixelSeatConfig, seed: int, out, progress: bool = True) -> dict:
    """Collect, fit, validate for ``config.rounds`` rounds; the best validated round is the policy
    (``<out>/policies/<name>``, :func:`keep_best`); ``<out>/result.json`` records every round (rewritten after each,
    ``selected_round`` null until the last)."""
    from dvrl_marl import policies

    torch = _torch()
    if config.threads:
        torch.set_num_threads(config.threads)
    torch.manual_seed(seed)
    out = Path(out)
    began = time.perf_counter()
    model = PixelActor(config, config.proprioception[1] - config.proprioception[0])
    data: dict | None = None
    rounds = []
    student = constants = None
    for index in range(config.rounds):
        world_seed = PIXEL_SEED + 1_000_000 * seed + index * config.worlds
        batch = collect(config, student, world_seed, noise_seed=world_seed)
        driven = batch.pop("success_rate")
        batch.pop("steps")
        seen_constants = batch.pop("constants")
        errors = (estimate_errors(model, batch, blood=_blood_columns(config), near_mm=config.near_mm)
                  if config.acts_by == "teacher" and index > 0 else None)
        constants = (seen_constants if constants is None  # (NaN where a value varied, in any round)
                     else np.where(constants == seen_constants, constants, np.nan))
        data = batch if data is None else {k: np.concatenate([data[k], batch[k]]) for k in data}
        loss = fit(model, data, config, config.first_updates if index == 0 else config.updates, seed * 1000 + index)
        candidate = export(model, config, round_folder(out, index), name,
                           {"teacher": config.teacher, "training": {"rounds": index + 1, "seed": seed,
                                                                    "frames": int(len(data["labels"]))}},
                           constants)
        student = policies.load(candidate)
        validation = validate(student, config)
        row = {"round": index, "driver": "teacher" if index == 0 else "student", "driver_success": driven,
               "frames": int(len(data["labels"])), "loss": round(loss, 5), "validation": validation,
               **({"estimate_errors_before_fit": errors} if errors else {}),
               "wall_seconds": round(time.perf_counter() - began, 1)}
        rounds.append(row)
        # each round's row as it comes: a run stopped early keeps its record (no round selected yet)
        (out / "result.json").write_text(json.dumps({"name": name, "seed": seed, "config": config.model_dump(),
                                                     "rounds": rounds, "selected_round": None}, indent=2) + "\n")
        if progress:
            print(f"round {index}: {row['driver']} drove ({driven:.0%}), {row['frames']:,d} frames, loss "
                  f"{row['loss']:.4f}, validation {validation['success_rate']:.0%} "
                  f"({validation['mean_contact_steps']:.1f} contacts), {row['wall_seconds']:.0f} s"
                  + (f", estimate errors on its frames before the fit {errors}" if errors else ""), flush=True)
    selected = keep_best(out, name, rounds)
    summary = {"name": name, "seed": seed, "config": config.model_dump(), "rounds": rounds, "selected_round": selected,
               "policy": str(out / "policies" / name), "wall_seconds": round(time.perf_counter() - began, 1)}
    (out / "result.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def round_folder(out, index: int) -> Path:
    """Where a run exports the policy of its DAgger round ``index``."""
    return Path(out) / "rounds" / f"round{index}"


def keep_best(out, name: str, rounds: list[dict]) -> int:
    """Copy the best validated round of ``rounds`` (``result.json``'s rows) from ``<out>/rounds`` to
    ``<out>/policies/<name>``; returns its index. Best: the highest success, then the fewest contact steps; a tie
    goes to the later round, which has learnt from more of the frames its predecessors drove."""
    import shutil

    out = Path(out)
    index = max(range(len(rounds)), key=lambda i: (rounds[i]["validation"]["success_rate"],
                                                   -rounds[i]["validation"]["mean_contact_steps"], i))
    folder = out / "policies" / name
    shutil.rmtree(folder, ignore_errors=True)
    shutil.copytree(round_folder(out, index), folder)
    spec = json.loads((folder / "policy.json").read_text())
    spec["training"]["selected_by"] = (f"validation success by the default call, best of {len(rounds)} DAgger "
                                       f"rounds (ties to the later): round {index}")
    (folder / "policy.json").write_text(json.dumps(spec, indent=2) + "\n")
    return index


def train_from_request(request, run_table: dict) -> int:
    """``dvrl-marl train`` with a pixel seat's configuration (``--export``: the chosen policy copied there)."""
    name, config = load_config(request.config)
    out = request.out_folder(name)
    result = train(name, config, request.seed, out, progress=request.progress)
    chosen = result["rounds"][result["selected_round"]]["validation"]
    print(f"{name} seed {request.seed}: validation success {chosen['success_rate']:.0%} (round "
          f"{result['selected_round']}) in {result['wall_seconds']:.0f} s; policy in {result['policy']}")
    if request.export:
        import shutil

        shutil.copytree(result["policy"], request.export, dirs_exist_ok=True)
        print(f"exported the policy to {request.export}")
    return 0


TRAINER = trainers.register(trainers.Trainer(
    name="pixel-dagger", algorithms=("pixel-dagger",), run=train_from_request, takes=frozenset({"export"}),
    needs=("torch",), install='pip install "dvrl-marl[train]"',
    summary="a seat that sees the endoscope, distilled from a privileged seat (DAgger)"))

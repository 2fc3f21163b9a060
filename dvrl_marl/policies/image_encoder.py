"""The convolutional encoder of a policy that sees the endoscope: numpy inference, no torch.

A pixel policy's ``policy.json`` has an ``"image"`` table: the observation key of the image and its size (with
``stereo``, the stereo pair's: the key's image, the left eye's, and ``<key>_right``, read as six channels), the
slice of the ``"observation"`` vector it reads as proprioception (the arm's own tip and tool: what the robot's
joints tell it), its convolutions ``[channels, kernel, stride]`` (no padding, ReLU after each) and optionally a
``readout``: a linear layer of that many outputs after them (estimates of what the scene holds, such as the blood
left). ``policy.npz`` holds the kernels ``K0, k0, K1, k1, ...`` in torch's layout ``(out, in, kernel, kernel)`` and the
read-out's ``R, r``. The encoder's output (the convolutions' flattened channels first, as torch flattens them, or the
read-out's) followed by the proprioception is what the policy's first layer reads; or, with a ``fills`` table, the
read-out's estimates fill a state policy's observation (a template of the scene's constants, the proprioception at
its own indices), which the policy reads as it would the env's (its ``features`` computed from it): a privileged
policy acting on what the image tells it. ``fills.keep_lowest`` names the estimates (observation indices) kept, world
by world, at their lowest value since the episode began (the policy's ``reset(worlds)`` starts episodes; the
evaluations and the seats call it); with ``fills.full_above`` those kept at that or more read as full (1: a
cavity's whole blood, all its teacher ever read of a cavity not yet touched). ``fills.relative`` names estimates
read as offsets from the arm's own values (the other arm's tip from the own tip): the proprioception is added back
before they fill the observation.

With ``keypoints`` the read-out reads more than the convolutions' output: after it, two keypoints per channel of the
last convolution (a spatial softmax, Levine et al. 2016: each channel's softmax over its positions, its logits the
channel times a gain of its own, ``policy.npz``'s ``G``; the expected column of every channel, then the expected row,
each from -1 at the image's left or top to 1), then the proprioception. A view moved or turned moves a keypoint by
as much, which a linear read-out of keypoints can take away (the phantom's and the own instrument's keypoints tell
how far it moved); a read-out of the flattened output meets such a move only as far as training showed it.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from dvrl_marl.schemas import PolicyImage, validated

__all__ = ["ImageEncoder", "NORMALISE_FLOOR", "FULL", "NEW_EPISODE_JUMP", "keypoints"]

#: ``normalise = "per_image"``: added to a channel's spread (``"brightness"``: to an image's mean), so that a flat
#: (or black) image is not blown up.
NORMALISE_FLOOR = 0.02

#: ``keep_lowest``: a move of the tip (the proprioception's first three values, the observation's ``own_tip``) this
#: large or larger in one call starts the world's episode anew, as a reset does: the tip moves at most 0.022 a step
#: (measured: every action at +-1), and a new episode puts it back at its start (0.117 or more away in 64 episodes of
#: such moves). A seat called across episodes without ``reset()`` kept the last episode's emptied cavities and
#: finished 1 of 20 episodes beside the scripted surgeon.
NEW_EPISODE_JUMP = 0.05

#: A cavity's blood left when it is full, in the observation's terms (its share of the cavity's start): what
#: ``fills.full_above`` reads an estimate as.
FULL = 1.0


class ImageEncoder:
    """``encoder(images, own)``: uint8 images ``(..., S, S, 3)`` and the proprioception ``(..., p)`` (read only with
    ``keypoints``) -> float32 features ``(..., encoded_size)``."""

    def __init__(self, image: dict, kernels: list[tuple[np.ndarray, np.ndarray]],
                 readout: tuple[np.ndarray, np.ndarray] | None = None, keypoint_gains: np.ndarray | None = None):
        checked = validated(PolicyImage, image, "policy.json's image")
        self.key, self.size, self.normalise = checked.key, checked.size, checked.normalise
        #: the stereo pair's (the left eye's channels, then the right eye's ``<key>_right``) or one image's
        self.stereo, self.channels = checked.stereo, 6 if checked.stereo else 3
        self.keys = (self.key, f"{self.key}_right") if self.stereo else (self.key,)
        self.convolutions = [tuple(layer) for layer in checked.convolutions]
        if kernels and np.shape(kernels[0][0])[1:2] != (self.channels,):
            raise ValueError(f"policy.npz's first kernel reads {np.shape(kernels[0][0])[1:2]} channels; the image "
                             f"table gives {self.channels} ({'the stereo pair' if self.stereo else 'RGB'})")
        self.proprioception = slice(*checked.proprioception)
        self.kernels = [(w.astype(np.float32), b.astype(np.float32)) for w, b in kernels]
        self.output_size = checked.encoded_size()
        self.readout = None if readout is None else tuple(part.astype(np.float32) for part in readout)
        self.keypoint_gains = None
        if checked.keypoints:
            if keypoint_gains is None or np.shape(keypoint_gains) != (self.convolutions[-1][0],):
                raise ValueError(f"policy.json's image reads keypoints: it needs one softmax gain per channel of the "
                                 f"last convolution ({self.convolutions[-1][0]}), got "
                                 f"{None if keypoint_gains is None else np.shape(keypoint_gains)}")
            self.keypoint_gains = np.asarray(keypoint_gains, dtype=np.float32)
        # a state policy's observation to fill (the scene's constants), or None: the encoding then the proprioception
        self.fills = None
        self.keep_lowest = None  # the read-out's outputs kept at their lowest (a boolean mask), or None
        if checked.fills is not None:
            self.fills = (np.asarray(checked.fills.template, dtype=np.float64), np.asarray(checked.fills.estimates_at))
            kept = np.isin(checked.fills.estimates_at, checked.fills.keep_lowest)
            self.keep_lowest = kept if kept.any() else None
        self._lowest = None  # keep_lowest: the lowest estimates of each world's episode so far
        self._last_tip = None  # keep_lowest: each world's tip at the last call (a jump starts a new episode)
        # keep_lowest's estimates at this or more read as full (1), or None
        self.full_above = None if checked.fills is None else checked.fills.full_above
        # fills.relative: the read-out's outputs that are offsets, and the proprioception's entries added to them
        self.relative = None
        if checked.fills is not None and checked.fills.relative:
            at, start = list(checked.fills.estimates_at), checked.proprioception[0]
            self.relative = (np.array([at.index(estimated) for estimated, _ in checked.fills.relative]),
                             np.array([own - start for _, own in checked.fills.relative]))
        if (self.readout is None) != (checked.readout is None):
            raise ValueError(f"policy.json's image names a readout of {checked.readout} outputs, "
                             f"{'without' if self.readout is None else 'with'} weights for it")

    def observation(self, images, observation) -> np.ndarray:
        """What the policy's layers read: the filled observation (the template, the env observation's
        proprioception at its own indices, the estimates at theirs), or the encoding followed by the
        proprioception."""
        # a network of its own trained on float32 proprioception; a teacher's layers read the float64 observation
        own = np.asarray(observation, dtype=np.float32 if self.fills is None else np.float64)[..., self.proprioception]
        own = own.astype(np.float64)
        if self.fills is None:
            return np.concatenate([self(images, own).astype(np.float64), own], axis=-1)
        encoded = self.estimates(images, own)
        if self.keep_lowest is not None:
            self._start_jumped_episodes(own)
            encoded = np.where(self.keep_lowest, self._kept_lowest(encoded), encoded)
            if self.full_above is not None:
                encoded = np.where(self.keep_lowest & (encoded >= self.full_above), FULL, encoded)
        return self.filled(own, encoded)

    def estimates(self, images, own) -> np.ndarray:
        """The read-out's estimates in the observation's terms (a ``fills`` policy): the offsets ``fills.relative``
        names with ``own`` (the proprioception) added back; none kept at its lowest."""
        estimates = self(images, own).astype(np.float64)
        if self.relative is not None:
            outputs, entries = self.relative
            estimates[..., outputs] += np.asarray(own, dtype=np.float64)[..., entries]
        return estimates

    def filled(self, own: np.ndarray, estimates: np.ndarray) -> np.ndarray:
        """The teacher's observation (``fills``): the scene's constants, ``own`` (the proprioception) at its indices,
        ``estimates`` at theirs (the read-out's, or the truth's to ask what exact estimates would give)."""
        template, estimates_at = self.fills
        filled = np.broadcast_to(template, own.shape[:-1] + template.shape).copy()
        filled[..., self.proprioception] = own
        filled[..., estimates_at] = estimates
        return filled

    def reset(self, worlds=None) -> None:
        """Start the episodes of ``worlds`` (a boolean mask or indices over the batch; None: every world): the
        lowest estimates kept (``keep_lowest``) are forgotten there."""
        if self._lowest is None or worlds is None:
            self._lowest = self._last_tip = None
            return
        self._lowest[np.asarray(worlds)] = np.inf

    def _start_jumped_episodes(self, own: np.ndarray) -> None:
        """The worlds whose tip jumped (:data:`NEW_EPISODE_JUMP`) since the last call start new episodes: their
        lowest estimates are forgotten, as :meth:`reset` would (a caller that never resets is not misled)."""
        tip = np.asarray(own, dtype=np.float64)[..., :3]
        if self._last_tip is not None and self._last_tip.shape == tip.shape and self._lowest is not None:
            jumped = np.linalg.norm(tip - self._last_tip, axis=-1) >= NEW_EPISODE_JUMP
            if self._lowest.shape[:-1] == jumped.shape and np.any(jumped):
                self._lowest = np.where(jumped[..., None], np.inf, self._lowest)
        self._last_tip = tip.copy()

    def _kept_lowest(self, estimates: np.ndarray) -> np.ndarray:
        """Each estimate the lowest its world's episode has seen (the caller keeps those ``keep_lowest`` names). Why:
        without bleeding a cavity's blood only falls, and a cleared cavity that the other instrument covers in the
        image reads as full again (measured: beside a partner over a cavity the seat went back to it, 200+ contact
        steps an episode; keeping the lowest, none).
        A batch of another shape starts new episodes."""
        if self._lowest is None or self._lowest.shape != estimates.shape:
            self._lowest = estimates
        else:
            self._lowest = np.minimum(self._lowest, estimates)
        return self._lowest  # (the caller writes it into its filled observation: a copy)

    def image(self, observation: dict) -> np.ndarray:
        """What the convolutions read of an env's observation dict: its image, or the stereo pair's two side by
        side in the channels (left, then right)."""
        eyes = [np.asarray(observation[key]) for key in self.keys]
        for key, eye in zip(self.keys, eyes):
            if eye.dtype != np.uint8:  # (floats in 0..1 read as black, uint16 as glare; NaN cannot be uint8)
                raise ValueError(f"the policy reads {key!r} as the env draws it, uint8 RGB in 0..255, got {eye.dtype}")
            if eye.ndim < 3 or eye.shape[-3:] != (self.size, self.size, 3) or eye.shape[:-3] != eyes[0].shape[:-3]:
                raise ValueError(f"the policy reads {key!r} as {self.size} x {self.size} RGB images "
                                 f"(..., {self.size}, {self.size}, 3), one per world as the other eye's (make the env "
                                 f"with image_size={self.size}), got shape {eye.shape}")
        return eyes[0] if len(eyes) == 1 else np.concatenate(eyes, axis=-1)

    def __call__(self, images, own=None) -> np.ndarray:
        images = np.asarray(images)
        if images.shape[-3:] != (self.size, self.size, self.channels):
            seen = "the stereo pair's images (image_stereo=True)" if self.stereo else "RGB images"
            raise ValueError(f"the policy sees {self.size} x {self.size} {seen} (make the env with "
                             f"image_size={self.size}), got an image of shape {images.shape[-3:]}")
        lead = images.shape[:-3]
        x = images.reshape((-1,) + images.shape[-3:]).astype(np.float32) / 255.0
        if self.normalise == "per_image":  # each channel of each image at zero mean, unit spread
            x = (x - x.mean(axis=(1, 2), keepdims=True)) / (x.std(axis=(1, 2), keepdims=True) + NORMALISE_FLOOR)
        elif self.normalise == "brightness":  # each image's mean at 0.5 (an exposure), then in [-0.5, ...]
            x = x * (0.5 / (x.mean(axis=(1, 2, 3), keepdims=True) + NORMALISE_FLOOR)) - 0.5
        else:  # pixels in [-0.5, 0.5], as the trainer fed them
            x = x - 0.5
        for (weight, bias), (_, kernel, stride) in zip(self.kernels, self.convolutions):
            windows = sliding_window_view(x, (kernel, kernel), axis=(1, 2))[:, ::stride, ::stride]
            # windows: (N, H', W', in, k, k) against torch's (out, in, k, k)
            x = np.maximum(np.tensordot(windows, weight, axes=([3, 4, 5], [1, 2, 3])) + bias, 0.0)
        points = None if self.keypoint_gains is None else keypoints(x, self.keypoint_gains)
        x = x.transpose(0, 3, 1, 2).reshape(len(x), -1)
        if points is not None:
            if own is None:
                raise ValueError("this encoder's read-out reads the proprioception beside the image's keypoints: "
                                 "call it with the observation's proprioception")
            own = np.asarray(own, dtype=np.float32).reshape(len(x), -1)
            x = np.concatenate([x, points, own], axis=1)
        if self.readout is not None:
            x = x @ self.readout[0].T + self.readout[1]
        return x.reshape(lead + (-1,))


def keypoints(x: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """A spatial softmax: ``x`` ``(N, H, W, C)`` -> ``(N, 2 C)``, each channel's expected column (all channels), then
    its expected row, from -1 at the left or top to 1, under the softmax of the channel times its gain."""
    count, height, width, channels = x.shape
    logits = (x * gains).reshape(count, height * width, channels)
    weights = np.exp(logits - logits.max(axis=1, keepdims=True))
    weights = (weights / weights.sum(axis=1, keepdims=True)).reshape(count, height, width, channels)
    columns = np.einsum("nhwc,w->nc", weights, np.linspace(-1.0, 1.0, width, dtype=np.float32))
    rows = np.einsum("nhwc,h->nc", weights, np.linspace(-1.0, 1.0, height, dtype=np.float32))
    return np.concatenate([columns, rows], axis=1).astype(np.float32)

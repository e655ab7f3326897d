"""Channels by name: the interface map's inputs and outputs matched to each model's.

The validator's channels are the interface map's sources: its inputs (in map order) and its
outputs. A model names its inputs and outputs (``LFTModel.input_names``/``output_names``);
each of them is looked up by name among the channels, never by position. Several models in
one validator share the channels they name: every model's names must be channels of the map,
and every channel must be named by some model (a channel no model reads, or a model channel
the map does not carry, is an error that lists both sides and the fix).

Nothing here imports ROS; the matching is a pure function of the names.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from twotank_validation.core.model import LFTModel
from twotank_validation.errors import TwotankError


class ChannelError(TwotankError, ValueError):
    """A model's channels do not match the interface map's by name (both sides are listed)."""


@dataclass(frozen=True)
class ModelChannels:
    """Where one model's inputs and outputs sit among the validator's channels.

    Attributes:
        inputs: (n_u of the model,) index into the validator's inputs of each model input.
        outputs: (n_y of the model,) index into the validator's outputs of each model output.
        identity: the model takes every channel in the validator's order (no reordering).
    """

    inputs: tuple[int, ...]
    outputs: tuple[int, ...]
    identity: bool

    def select(self, u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A window's columns as the model orders them.

        Args:
            u: (n, n_inputs) float, in the validator's channel order.
            y: (n, n_outputs) float, likewise.

        Returns:
            ``(n, model n_u)`` and ``(n, model n_y)``: the same arrays when :attr:`identity`.
        """
        if self.identity:
            return u, y
        return u[:, list(self.inputs)], y[:, list(self.outputs)]


@dataclass(frozen=True)
class Channels:
    """The validator's channels and each model's place among them.

    Attributes:
        input_names: the inputs, in the order of the samples' ``u`` columns.
        output_names: the outputs, in the order of the samples' ``y`` columns.
        models: model name -> :class:`ModelChannels`.
    """

    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    models: Mapping[str, ModelChannels]

    @property
    def n_inputs(self) -> int:
        """Number of inputs."""
        return len(self.input_names)

    @property
    def n_outputs(self) -> int:
        """Number of outputs."""
        return len(self.output_names)


def _listing(names: Sequence[str]) -> str:
    return "[" + ", ".join(names) + "]"


def match_channels(
    input_names: Sequence[str],
    output_names: Sequence[str],
    models: Sequence[LFTModel],
    *,
    source: str = "the interface map",
) -> Channels:
    """Match each model's inputs and outputs to the channels by name.

    Args:
        input_names: the channels' inputs (the map's input names, in map order).
        output_names: the channels' outputs.
        models: the models judged on these channels.
        source: what carries the channels, for messages (e.g. ``"the interface map rig.yaml"``).

    Returns:
        The channels with each model's indices.

    Raises:
        ChannelError: A model names a channel the map does not carry, or a channel of the map
            is named by no model; the message lists the model's and the map's names and says
            how to make them agree.
    """
    ins, outs = tuple(input_names), tuple(output_names)
    in_index = {n: i for i, n in enumerate(ins)}
    out_index = {n: i for i, n in enumerate(outs)}
    used_in: set[str] = set()
    used_out: set[str] = set()
    placed: dict[str, ModelChannels] = {}
    for m in models:
        missing = [f"input {n!r}" for n in m.input_names if n not in in_index] + [
            f"output {n!r}" for n in m.output_names if n not in out_index
        ]
        if missing:
            raise ChannelError(
                f"model {m.name} names {', '.join(missing)}, which {source} does not carry: the "
                f"model has inputs {_listing(m.input_names)} and outputs "
                f"{_listing(m.output_names)}; {source} has inputs {_listing(ins)} and outputs "
                f"{_listing(outs)}. Channels are matched by name: give a map whose sources "
                "carry the model's names (--map FILE or --input/--output NAME=...; "
                "docs/interface.md), or rename the model's channels"
            )
        used_in.update(m.input_names)
        used_out.update(m.output_names)
        idx_in = tuple(in_index[n] for n in m.input_names)
        idx_out = tuple(out_index[n] for n in m.output_names)
        identity = idx_in == tuple(range(len(ins))) and idx_out == tuple(range(len(outs)))
        placed[m.name] = ModelChannels(idx_in, idx_out, identity)
    extra = [f"input {n!r}" for n in ins if n not in used_in] + [
        f"output {n!r}" for n in outs if n not in used_out
    ]
    if extra and models:
        names = ", ".join(
            f"{m.name} (inputs {_listing(m.input_names)}, outputs {_listing(m.output_names)})"
            for m in models
        )
        raise ChannelError(
            f"{source} carries {', '.join(extra)}, which no model names: the models are "
            f"{names}; {source} has inputs {_listing(ins)} and outputs {_listing(outs)}. "
            "Channels are matched by name: drop the channel from the map, or judge a model "
            "that names it"
        )
    return Channels(ins, outs, placed)

"""The keyword arguments that make the collaborative scene, spelled out once for every form's signature.

``parallel_env``, ``env``, ``batched_env`` and ``jax_env`` take the same keywords, each form adding its own few (a
seat and a window for the parallel env; ``num_envs``, ``autoreset_mode`` and a device for the batched one). They pass
them on as ``**kwargs``; :func:`form_signature` writes them out for ``inspect.signature`` (what ``help()``, IPython
and Jupyter show and complete): the form's own keywords, the option records' fields
(:mod:`dvrl_marl.suction_debris.scene_options`), ``preset``, and the task's parameters
(:class:`~dvrl_marl.suction_debris.task.SuctionDebrisParams`), each annotated with its checked type (its range),
with its default (the task file's value). Nothing here checks a value: the env does, once, where it is made
(:meth:`~dvrl_marl.suction_debris.scene_options.SceneOptions.of`).
"""

from __future__ import annotations

import functools
import inspect
from dataclasses import fields

from dvrl_marl.suction_debris.scene_options import RECORDS
from dvrl_marl.suction_debris.task import TASK, SuctionDebrisParams

__all__ = ["form_signature", "scene_keywords"]

_KEYWORD = inspect.Parameter.KEYWORD_ONLY


@functools.cache
def _task_defaults() -> dict:
    """The task file's values of the task's parameters (what a keyword left out takes)."""
    params = SuctionDebrisParams.from_task(TASK)
    return {item.name: getattr(params, item.name) for item in fields(SuctionDebrisParams)}


def scene_keywords(*inits, without=()) -> list[inspect.Parameter]:
    """The keywords that make the scene, as keyword-only parameters: the named ones of each of ``inits`` (the
    batched env's constructor: a seat, rendering, the batch; a device env's own) but ``without`` and ``preset``, then
    the option records' fields by concern (:data:`dvrl_marl.suction_debris.scene_options.RECORDS`: the observation, the images,
    the learning aids), then ``preset``, then every task parameter, each record's and the task's with its default
    (the task file's value) and its checked type (its range) as its annotation."""
    own, named = [], {*without, "preset"}
    for init in inits:
        for name, parameter in inspect.signature(init).parameters.items():
            if name not in named and name != "self" and parameter.kind in (
                    inspect.Parameter.POSITIONAL_OR_KEYWORD, _KEYWORD):
                own.append(parameter.replace(kind=_KEYWORD))
                named.add(name)
    options = [inspect.Parameter(item.name, _KEYWORD, default=item.default, annotation=item.type)
               for record in RECORDS.values() for item in fields(record) if item.name not in named]
    named.update(parameter.name for parameter in options)
    defaults = _task_defaults()
    task = [inspect.Parameter(item.name, _KEYWORD, default=defaults[item.name], annotation=item.type)
            for item in fields(SuctionDebrisParams) if item.name not in named]
    preset = inspect.Parameter("preset", _KEYWORD, default="default", annotation="str")
    return own + options + [preset] + task


def form_signature(function, *inits, without=()) -> inspect.Signature:
    """``function``'s signature with its ``**kwargs`` written out as :func:`scene_keywords` of ``inits`` (``without``
    the keywords the form does not take)."""
    signature = inspect.signature(function)
    leading = [parameter for parameter in signature.parameters.values()
               if parameter.kind is not inspect.Parameter.VAR_KEYWORD]
    keywords = scene_keywords(*inits, without=(*without, *(parameter.name for parameter in leading)))
    return signature.replace(parameters=[*leading, *keywords])

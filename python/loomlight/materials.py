"""Materials: a preset, a model with parameters, or a preset with some overridden, checked against the server's
parameter schemas (ListModels) before they are sent. The server checks them again; checking here turns a typo
into an error at the line that made it, before any call."""
import math
from dataclasses import dataclass, field
from typing import Dict, Optional, Sequence, Union

from ._api import pb
from .errors import invalid_argument

ParamValue = Union[float, int, Sequence[float], str]


@dataclass
class Material:
    """A material as the API takes it (loomlight.v1.Material).

    `params` maps parameter names (ListModels' schema, e.g. "thread1.albedo") to a number, a sequence of numbers
    (an RGB triple, a list) or a string (a text parameter such as a WIF draft). `transmission` makes a curtain:
    a `thin_layer` material whose layer the light passes through."""

    preset: str = ""
    model: str = ""
    params: Dict[str, ParamValue] = field(default_factory=dict)
    transmission: Optional["Material"] = None

    def with_params(self, **params):
        """A copy with these parameters overridden (a "__" in a keyword stands for the "." of "thread1.albedo")."""
        merged = dict(self.params)
        merged.update({name.replace("__", "."): value for name, value in params.items()})
        return Material(self.preset, self.model, merged, self.transmission)

    def to_proto(self):
        message = pb.Material(preset=self.preset, model=self.model)
        add_params(message.params, self.params)
        if self.transmission is not None:
            message.transmission.CopyFrom(self.transmission.to_proto())
        return message

    @classmethod
    def from_proto(cls, message):
        params = {}
        for param in message.params:
            if param.text:
                params[param.name] = param.text
            elif len(param.values) == 1:
                params[param.name] = param.values[0]
            else:
                params[param.name] = tuple(param.values)
        transmission = cls.from_proto(message.transmission) if message.HasField("transmission") else None
        return cls(message.preset, message.model, params, transmission)


def add_params(container, params):
    """Appends {name: value} to a repeated loomlight.v1.Param: a string as text, a number as one value, a sequence
    as its values (material and scene parameters alike)."""
    for name, value in params.items():
        param = container.add(name=name)
        if isinstance(value, str):
            param.text = value
        elif isinstance(value, (int, float)):
            param.values.append(float(value))
        else:
            param.values.extend(float(v) for v in value)


MaterialLike = Union[Material, str, "pb.Material"]


def as_material(value):
    """A Material from a Material, a preset name, or a loomlight.v1.Material message."""
    if isinstance(value, Material):
        return value
    if isinstance(value, str):
        return Material(preset=value)
    if isinstance(value, pb.Material):
        return Material.from_proto(value)
    raise TypeError(f"a material is a loomlight.Material, a preset name or a loomlight.v1.Material, not "
                    f"{type(value).__name__}")


def _short(text, limit=64):
    text = str(text)
    return text if len(text) <= limit else text[:limit] + "..."


def _number(value):
    return "%.6g" % value


class Schemas:
    """The models' parameter schemas and presets (a ListModelsResponse), for checking materials client-side."""

    def __init__(self, list_models_response):
        self.response = list_models_response
        self.models = {model.name: model for model in list_models_response.models}
        self.preset_models = {}
        for model in list_models_response.models:
            for preset in model.presets:
                self.preset_models[preset.name] = model.name

    def model_of(self, material, where="material"):
        """The ModelInfo a material uses; raises InvalidArgumentError naming the field."""
        if material.preset:
            model = self.preset_models.get(material.preset)
            if model is None:
                raise invalid_argument(f"{where}.preset: no preset '{_short(material.preset)}' (ListModels lists them)")
            if material.model and material.model != model:
                raise invalid_argument(f"{where}.model: '{_short(material.model)}' is not the model of preset "
                                       f"'{material.preset}' ({model})")
            return self.models[model]
        if not material.model:
            raise invalid_argument(f"{where}: name a preset or a model")
        if material.model not in self.models:
            raise invalid_argument(f"{where}.model: no model '{_short(material.model)}' (known: "
                                   f"{', '.join(sorted(self.models))})")
        return self.models[material.model]

    def check(self, material, where="material"):
        """Checks every parameter's name, type, count and range against the schema, as the server does."""
        material = as_material(material)
        model = self.model_of(material, where)
        schema = {param.name: param for param in model.params}
        for index, (name, value) in enumerate(material.params.items()):
            at = f"{where}.params[{index}]"
            param = schema.get(name)
            if param is None:
                raise invalid_argument(f"{at}.name: model '{model.name}' has no parameter '{_short(name)}'")
            if param.type == pb.ParamSchema.TYPE_TEXT:
                if not isinstance(value, str):
                    raise invalid_argument(f"{at} ({name}): a text parameter takes a string")
                if len(value.encode("utf-8")) > param.max_count:
                    raise invalid_argument(f"{at} ({name}): {len(value.encode('utf-8'))} bytes, at most "
                                           f"{param.max_count}")
                continue
            if isinstance(value, str):
                raise invalid_argument(f"{at} ({name}): takes numbers, not text")
            values = [value] if isinstance(value, (int, float)) else list(value)
            if not param.min_count <= len(values) <= param.max_count:
                expected = (str(param.min_count) if param.min_count == param.max_count
                            else f"{param.min_count} to {param.max_count}")
                raise invalid_argument(f"{at} ({name}): {len(values)} values, {expected} expected")
            for v in values:
                try:
                    v = float(v)
                except (TypeError, ValueError):
                    raise invalid_argument(f"{at} ({name}): '{_short(v)}' is not a number") from None
                if not math.isfinite(v) or not param.min <= v <= param.max:
                    raise invalid_argument(f"{at} ({name}): {_number(v)} is outside [{_number(param.min)}, "
                                           f"{_number(param.max)}]")
                if param.type == pb.ParamSchema.TYPE_INT and v != int(v):
                    raise invalid_argument(f"{at} ({name}): {_number(v)} is not an integer")
        if material.transmission is not None:
            layer = self.model_of(material.transmission, f"{where}.transmission")
            if not layer.transmission:
                raise invalid_argument(f"{where}.transmission: model '{layer.name}' has no transmission")
            self.check(material.transmission, f"{where}.transmission")
        return model

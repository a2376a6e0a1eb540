"""Checks examples/scene.schema.json: every shipped scene validates, and
scenes with the faults brdfkit rejects (unknown key, wrong type, missing
field, bad name) are rejected by the schema as well."""
import copy
import json
import pathlib
import sys

import jsonschema

root = pathlib.Path(sys.argv[1])
schema = json.loads((root / "examples" / "scene.schema.json").read_text())
jsonschema.Draft202012Validator.check_schema(schema)
validator = jsonschema.Draft202012Validator(schema)

scenes = sorted(p for p in (root / "examples").glob("*.json") if p.name != "scene.schema.json")
assert scenes, "no example scenes"
for p in scenes:
    errors = list(validator.iter_errors(json.loads(p.read_text())))
    assert not errors, f"{p.name}: {errors[0].message} at {list(errors[0].absolute_path)}"

base = json.loads((root / "examples" / "default.json").read_text())


def rejected(mutate, what):
    s = copy.deepcopy(base)
    mutate(s)
    assert list(validator.iter_errors(s)), f"schema accepts a scene with {what}"


rejected(lambda s: s["tasks"][3].update({"metirc": "l2"}), "an unknown task key")
rejected(lambda s: s["tasks"][1].update({"axes": 32}), "a number for axes")
rejected(lambda s: s["tasks"][2].pop("instrument"), "a synth task without an instrument")
rejected(lambda s: s["tasks"][0].update({"type": "render"}), "an unknown task type")
rejected(lambda s: s.update({"outpt": "x"}), "an unknown top-level key")
rejected(lambda s: s["materials"].update({"bad name": {"model": "ggx"}}), "a name with a space")
rejected(lambda s: s["materials"].update({"two": {"model": "ggx", "merl": "x.binary"}}), "two material kinds")
rejected(lambda s: s["tasks"][3].update({"metric": "l3"}), "an unknown metric")
rejected(lambda s: s["tasks"][3].update({"fix": 0.04}), "a number for fix (name=value text)")
rejected(lambda s: s["tasks"][3].update({"bounds": ["ggx.alpha=0.01:0.5"]}), "a list for bounds")
rejected(lambda s: s["tasks"][1].update({"material": "plastic"}), "an albedo task with a model and a material")

# An albedo task over a material of the scene (mu alone by default) validates.
material_table = copy.deepcopy(base)
albedo = next(t for t in material_table["tasks"] if t["type"] == "albedo" and "model" in t)
for key in ("model", "params", "axes"):
    albedo.pop(key, None)
albedo["material"] = next(iter(material_table["materials"]))
errors = list(validator.iter_errors(material_table))
assert not errors, f"an albedo task over a material: {errors[0].message}"
print(f"{len(scenes)} example scene(s) valid, and an albedo task over a material; 11 faulty scenes rejected")

// The material being designed: a model, the preset it started from, and the parameters edited since.
import { create } from "@bufbuild/protobuf";
import type { Material, ModelInfo } from "../gen/loomlight/v1/loomlight_pb.js";
import { MaterialSchema, ParamSchema$ } from "../gen/loomlight/v1/loomlight_pb.js";
import type { ParamValue } from "./controls.js";

export class MaterialState {
  model!: ModelInfo;
  preset = ""; // the preset edits are made against ("" = the model's defaults)
  overrides = new Map<string, ParamValue>();

  select(model: ModelInfo, preset: string): void {
    this.model = model;
    this.preset = preset;
    this.overrides.clear();
  }

  /** Every parameter's current value: schema defaults, then the preset's, then the edits. */
  values(): Map<string, ParamValue> {
    const out = new Map<string, ParamValue>();
    for (const p of this.model.params) out.set(p.name, { values: [...p.defaultValues], text: "" });
    const preset = this.model.presets.find((p) => p.name === this.preset);
    for (const p of preset?.params ?? []) out.set(p.name, { values: [...p.values], text: p.text });
    for (const [name, v] of this.overrides) out.set(name, v);
    return out;
  }

  /**
   * The material as sent: the preset with only the edited parameters (in schema order), so the server's
   * `material.params[i]` in a refusal names the i-th entry of `sent`.
   */
  build(): { material: Material; sent: string[] } {
    const sent = this.model.params.map((p) => p.name).filter((n) => this.overrides.has(n));
    const params = sent.map((name) => {
      const v = this.overrides.get(name)!;
      return create(ParamSchema$, { name, values: v.values, text: v.text ?? "" });
    });
    return { material: create(MaterialSchema, { model: this.model.name, preset: this.preset, params }), sent };
  }
}

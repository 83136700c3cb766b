// Parameter controls built from ListModels' ParamSchema alone: the page names no parameter itself.
import type { ParamSchema } from "../gen/loomlight/v1/loomlight_pb.js";
import { ParamSchema_Type } from "../gen/loomlight/v1/loomlight_pb.js";
import { hexToLinear, linearToHex } from "./color.js";

/** A parameter's value as the API carries it: numbers, or text for TYPE_TEXT. */
export interface ParamValue {
  values: number[];
  text?: string;
}

/** Called when the designer edits a parameter; `error` is set when the text does not parse (nothing sent). */
export type EditHandler = (name: string, value: ParamValue | null, error?: string) => void;

interface Control {
  schema: ParamSchema;
  root: HTMLDivElement;
  show(value: ParamValue): void;
  error: HTMLDivElement;
}

const TYPE_NAMES: Record<number, string> = {
  [ParamSchema_Type.REAL]: "real",
  [ParamSchema_Type.INT]: "int",
  [ParamSchema_Type.RGB]: "rgb",
  [ParamSchema_Type.REAL_LIST]: "list",
  [ParamSchema_Type.TEXT]: "text",
};

function fmt(x: number): string {
  // Enough digits to round-trip what a slider step can reach, without float noise.
  return String(Number(x.toPrecision(6)));
}

function el<K extends keyof HTMLElementTagNameMap>(tag: K, props: Record<string, unknown> = {}): HTMLElementTagNameMap[K] {
  return Object.assign(document.createElement(tag), props);
}

export class ParamControls {
  private controls = new Map<string, Control>();

  constructor(private container: HTMLElement, private onEdit: EditHandler) {}

  /** Replaces the controls with one per parameter of `params`, in schema order. */
  build(params: ParamSchema[]): void {
    this.container.replaceChildren();
    this.controls.clear();
    for (const schema of params) {
      const control = this.make(schema);
      this.controls.set(schema.name, control);
      this.container.appendChild(control.root);
    }
  }

  show(values: Map<string, ParamValue>): void {
    for (const [name, control] of this.controls) {
      const value = values.get(name);
      if (value) control.show(value);
    }
  }

  setError(name: string, message: string): void {
    const control = this.controls.get(name);
    if (!control) return;
    control.error.textContent = message;
    control.root.classList.toggle("refused", message !== "");
  }

  clearErrors(): void {
    for (const name of this.controls.keys()) this.setError(name, "");
  }

  private make(schema: ParamSchema): Control {
    const type = TYPE_NAMES[schema.type] ?? "real";
    const root = el("div", { className: "param", title: schema.description });
    root.dataset.param = schema.name;
    root.dataset.type = type;
    const id = `param-${schema.name.replace(/[^A-Za-z0-9_-]/g, "_")}`;
    const label = el("label", { htmlFor: id });
    label.append(el("span", { className: "name", textContent: schema.name }));
    const unit = schema.unit && schema.unit !== "1" ? schema.unit : "";
    const range = type === "text" ? `up to ${schema.maxCount} bytes` : `${fmt(schema.min)} to ${fmt(schema.max)}`;
    label.append(el("span", { className: "unit", textContent: unit ? ` (${unit})` : "" }));
    label.append(el("span", { className: "range", textContent: range }));
    root.appendChild(label);
    const row = el("div", { className: "inputs" });
    root.appendChild(row);
    const error = el("div", { className: "param-error" });
    error.setAttribute("role", "alert");
    let show: (value: ParamValue) => void;
    const edit = (value: ParamValue | null, err?: string) => this.onEdit(schema.name, value, err);

    if (type === "real" || type === "int") {
      // A round step (a power of ten, 500 to 5000 of them over the range), so the slider sends values as typed.
      const step = type === "int" ? 1 : 10 ** Math.floor(Math.log10((schema.max - schema.min) / 500));
      const slider = el("input", { type: "range", id, min: String(schema.min), max: String(schema.max) });
      slider.step = String(step);
      slider.dataset.role = "value";
      const number = el("input", { type: "number" });
      number.step = type === "int" ? "1" : "any";
      number.dataset.role = "number";
      number.setAttribute("aria-label", `${schema.name} value`);
      // The slider is live while dragged; the number is sent as typed (no clamping: the server judges it).
      slider.addEventListener("input", () => {
        number.value = fmt(Number(slider.value));
        edit({ values: [Number(slider.value)] });
      });
      number.addEventListener("change", () => {
        const x = Number(number.value);
        if (number.value.trim() === "" || !Number.isFinite(x)) return edit(null, `${schema.name}: enter a number`);
        slider.value = String(x);
        edit({ values: [x] });
      });
      row.append(slider, number);
      show = (v) => {
        slider.value = String(v.values[0]);
        number.value = fmt(v.values[0]);
      };
    } else if (type === "rgb") {
      const picker = el("input", { type: "color", id });
      picker.dataset.role = "value";
      const linear = el("span", { className: "linear" });
      linear.dataset.role = "linear";
      linear.title = "linear RGB values sent";
      const showLinear = (rgb: number[]) => (linear.textContent = rgb.map((x) => x.toFixed(3)).join(", "));
      picker.addEventListener("input", () => {
        const rgb = hexToLinear(picker.value);
        showLinear(rgb);
        edit({ values: rgb });
      });
      row.append(picker, linear);
      show = (v) => {
        picker.value = linearToHex(v.values);
        showLinear(v.values);
      };
    } else if (type === "list") {
      const input = el("input", { type: "text", id, spellcheck: false });
      input.dataset.role = "value";
      input.placeholder = schema.minCount === 0 ? "(empty)" : `${schema.minCount} to ${schema.maxCount} values`;
      input.addEventListener("change", () => {
        const parts = input.value.split(/[\s,;]+/).filter((s) => s !== "");
        const values = parts.map(Number);
        const bad = parts.find((s, i) => !Number.isFinite(values[i]));
        if (bad !== undefined) return edit(null, `${schema.name}: '${bad}' is not a number`);
        edit({ values });
      });
      row.append(input);
      show = (v) => (input.value = v.values.map(fmt).join(", "));
    } else {
      const area = el("textarea", { id, rows: 3, spellcheck: false });
      area.dataset.role = "value";
      area.addEventListener("change", () => edit({ values: [], text: area.value }));
      row.append(area);
      show = (v) => (area.value = v.text ?? "");
    }
    root.appendChild(error);
    return { schema, root, show, error };
  }
}

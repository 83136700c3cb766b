// Loomlight Studio: wires the material state, the controls and the views. Every edit is a numbered change
// (window.studio.change); each view redraws for it, aborting its own call for the change before.
import "./style.css";
import { Code, ConnectError } from "@connectrpc/connect";
import type { Material, ModelInfo } from "../gen/loomlight/v1/loomlight_pb.js";
import { ParamSchema_Type } from "../gen/loomlight/v1/loomlight_pb.js";
import { client, messageOf, paramIndexOf, setToken, token } from "./api.js";
import { listBtfs } from "./btfs.js";
import { ParamControls, type ParamValue } from "./controls.js";
import { wireDownloads } from "./downloads.js";
import { MaterialState } from "./material.js";
import { initTimings, timed } from "./timings.js";
import { drawHalfDiff } from "./views/halfdiff.js";
import { drawLobe, setLogRadius } from "./views/lobe.js";
import { drawSlice } from "./views/slice.js";
import { drawSphere } from "./views/sphere.js";
import { drawThumbnail, showFidelity } from "./views/thumbnail.js";
import { ViewSlot, type ViewContext, type ViewState } from "./views/view.js";

declare global {
  interface Window {
    studio: { change: number };
  }
}
window.studio = { change: 0 };

const $ = <T extends HTMLElement>(id: string) => document.getElementById(id) as T;
const statusEl = $("status");
const modelSelect = $<HTMLSelectElement>("model");
const presetSelect = $<HTMLSelectElement>("preset");
const sceneSelect = $<HTMLSelectElement>("scene");
const CUSTOM = "(custom)";
const SETTLE_MS = 50; // at most one round of calls this often while a slider is dragged

function showStatus(message: string, kind: "error" | "info" = "error"): void {
  statusEl.textContent = message.length > 300 ? message.slice(0, 297) + "..." : message;
  statusEl.dataset.kind = kind;
}
// Never a stack trace: one line in #status for anything the page did not catch.
window.addEventListener("error", (e) => showStatus(`page error: ${String(e.message).split("\n")[0]}`));
window.addEventListener("unhandledrejection", (e) => {
  e.preventDefault();
  showStatus(messageOf(e.reason));
});

const state = new MaterialState();
let models: ModelInfo[] = [];
let sent: string[] = [];
let material: Material | null = null;
const controls = new ParamControls($("params"), onEdit);

const slots = {
  lobe: new ViewSlot("lobe", $("lobe")),
  halfdiff: new ViewSlot("halfdiff", $("halfdiff")),
  sphere: new ViewSlot("sphere", $("sphere")),
  slice: new ViewSlot("slice", $("slice")),
  thumbnail: new ViewSlot("thumbnail", $("thumbnail")),
};

type Draw = (ctx: ViewContext) => Promise<ViewState | void>;
const draws: Record<keyof typeof slots, Draw> = {
  lobe: (ctx) => drawLobe($("lobe"), ctx, fiberAxis(ctx.model)),
  halfdiff: (ctx) => drawHalfDiff($("halfdiff"), ctx),
  sphere: (ctx) => drawSphere($("sphere"), ctx),
  slice: (ctx) => drawSlice($("slice"), ctx),
  thumbnail: (ctx) =>
    drawThumbnail(
      {
        img: $("thumbnail"),
        progress: $("render-progress"),
        caption: $("render-caption"),
        onFidelity: (u) => showFidelity($("fidelity"), u),
      },
      ctx,
      sceneSelect.value,
    ),
};

function fiberAxis(model: ModelInfo): number[] | null {
  if (!model.fiberAxisParam) return null;
  return state.values().get(model.fiberAxisParam)?.values ?? [1, 0, 0];
}

/** A refusal naming `material.params[i]` goes next to that control; anything else to #status. */
function report(error: unknown): void {
  const i = paramIndexOf(error);
  if (i >= 0 && i < sent.length) controls.setError(sent[i], messageOf(error));
  else showStatus(messageOf(error));
}

// Throttled, not debounced: an edit after a quiet spell goes out at once; edits while a slider is dragged go
// out at most every SETTLE_MS, each round with the latest material.
let timer: number | undefined;
let lastRun = -Infinity;
function changed(): void {
  window.studio.change += 1;
  for (const slot of Object.values(slots)) if (slot.element.dataset.state !== "hidden") slot.state = "busy";
  if (timer !== undefined) return; // the round already scheduled reads the state as it is then
  const wait = Math.max(0, lastRun + SETTLE_MS - performance.now());
  timer = window.setTimeout(() => {
    timer = undefined;
    lastRun = performance.now();
    runAll();
  }, wait);
}

function runAll(): void {
  const change = window.studio.change;
  ({ material, sent } = state.build());
  controls.clearErrors();
  if (statusEl.dataset.kind === "error") showStatus("", "info");
  for (const [name, slot] of Object.entries(slots))
    void slot.run(material, state.model, change, draws[name as keyof typeof slots], report);
}

function onEdit(name: string, value: ParamValue | null, error?: string): void {
  if (!value) {
    controls.setError(name, error ?? "");
    return;
  }
  state.overrides.set(name, value);
  showPresets();
  changed();
}

function showPresets(): void {
  const names = state.model.presets.map((p) => p.name);
  const custom = state.overrides.size > 0 || !state.preset;
  presetSelect.replaceChildren(
    ...(custom ? [CUSTOM] : []).concat(names).map((n) => new Option(n, n)),
  );
  presetSelect.value = custom ? CUSTOM : state.preset;
  const preset = state.model.presets.find((p) => p.name === state.preset);
  $("preset-description").textContent = preset ? preset.description : "";
}

function select(model: ModelInfo, preset: string): void {
  state.select(model, preset);
  modelSelect.value = model.name;
  $("model-description").textContent = model.description;
  controls.build(model.params);
  controls.show(state.values());
  showPresets();
}

function pickBtf(asset: string): void {
  const btf = models.find((m) => m.name === "btf");
  // The asset is named by the model's text parameter (the schema's, not a name written here).
  const param = btf?.params.find((p) => p.type === ParamSchema_Type.TEXT);
  if (!btf || !param) return showStatus("this server has no `btf` model");
  select(btf, "");
  state.overrides.set(param.name, { values: [], text: asset });
  controls.show(state.values());
  showPresets();
  changed();
}

// The token form: a new token reloads the page, so every call (ListModels first) carries it.
const tokenInput = $<HTMLInputElement>("token");
tokenInput.value = token();
$("token-form").addEventListener("submit", (event) => {
  event.preventDefault();
  setToken(tokenInput.value.trim());
  window.location.reload();
});

async function start(): Promise<void> {
  initTimings($("timings") as HTMLTableElement);
  const lobeLog = $<HTMLInputElement>("lobe-log");
  lobeLog.addEventListener("change", () => setLogRadius(lobeLog.checked));
  const scenes = loadScenes(); // in parallel with ListModels: the thumbnail needs it, the controls do not
  try {
    const reply = await timed("ListModels", "page", () => client.listModels({}));
    models = reply.models;
  } catch (error) {
    const message = messageOf(error);
    const code = error instanceof ConnectError ? error.code : Code.Unknown;
    if (code === Code.Unavailable) {
      showStatus(`S${message.slice(1)}. Reload the page once it is up.`);
    } else if (code === Code.Unauthenticated || code === Code.PermissionDenied) {
      showStatus(`The server wants a token that allows this page's calls (Token, top right): ${message}`);
    } else {
      showStatus(`The server did not list its models: ${message}`);
    }
    for (const slot of Object.values(slots)) slot.state = "error";
    return;
  }
  modelSelect.replaceChildren(...models.map((m) => new Option(m.name, m.name)));
  modelSelect.addEventListener("change", () => {
    const model = models.find((m) => m.name === modelSelect.value)!;
    select(model, model.presets[0]?.name ?? "");
    changed();
  });
  presetSelect.addEventListener("change", () => {
    if (presetSelect.value === CUSTOM) return;
    select(state.model, presetSelect.value);
    changed();
  });

  // Default (before anything else is awaited, so a choice made as soon as the list shows is not overridden):
  // the first model, at its velvet preset where it has one (the most telling lobe), else its first.
  const first = models[0];
  if (!first) return showStatus("the server has no models");
  select(first, first.presets.find((p) => p.name === "velvet")?.name ?? first.presets[0]?.name ?? "");
  changed();

  void listBtfs($("btfs"), pickBtf);
  $("btfs-refresh").addEventListener("click", () => void listBtfs($("btfs"), pickBtf));
  wireDownloads(() => state.build().material, showStatus);
  await scenes;
}

async function loadScenes(): Promise<void> {
  try {
    const scenes = await timed("ListScenes", "page", () => client.listScenes({}));
    sceneSelect.replaceChildren(
      ...scenes.scenes.map((s) => {
        const option = new Option(s.fibers ? `${s.name} (fiber models)` : s.name, s.name);
        option.title = s.description;
        return option;
      }),
    );
    sceneSelect.value = scenes.scenes.some((s) => s.name === "sphere") ? "sphere" : scenes.scenes[0]?.name ?? "";
  } catch (error) {
    showStatus(`scenes unavailable: ${messageOf(error)}`);
  }
  // Another scene is not another material: only the thumbnail redraws, for the same change.
  sceneSelect.addEventListener("change", () => {
    if (material) void slots.thumbnail.run(material, state.model, window.studio.change, draws.thumbnail, report);
  });
}

void start();

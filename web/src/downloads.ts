// Downloads of the current material: a MERL .binary and an in-plane EXR (Tabulate, streamed with progress) and
// a glTF sheen fit (FitMaterial GLB). Each is saved through a Blob URL and an <a download>.
import { create } from "@bufbuild/protobuf";
import type { Material } from "../gen/loomlight/v1/loomlight_pb.js";
import {
  ExportFormat,
  FitMaterialRequestSchema,
  FitTarget,
  TableFormat,
  TabulateRequestSchema,
  type TabulateRequest,
} from "../gen/loomlight/v1/loomlight_pb.js";
import { client, isAbort, messageOf } from "./api.js";
import { timed } from "./timings.js";

function save(bytes: Uint8Array[], name: string, type: string): void {
  const url = URL.createObjectURL(new Blob(bytes, { type }));
  const a = document.createElement("a");
  a.href = url;
  a.download = name;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 60_000); // long enough for the browser to have read it
}

function label(material: Material): string {
  return (material.preset || material.model || "material") + (material.params.length ? "-custom" : "");
}

async function tabulate(request: TabulateRequest, view: string, onProgress: (p: number) => void): Promise<Uint8Array[]> {
  const reply = await timed(
    "Tabulate",
    view,
    async () => {
      const chunks: Uint8Array[] = [];
      let seconds = 0;
      for await (const chunk of client.tabulate(request)) {
        if (chunk.data.length) chunks.push(chunk.data);
        if (chunk.cellsTotal > 0n) onProgress(Number(chunk.cellsDone) / Number(chunk.cellsTotal));
        seconds = chunk.totalSeconds || seconds; // the last chunk carries the server's time
      }
      return { chunks, seconds };
    },
    (r) => r.seconds,
  );
  return reply.chunks;
}

export function wireDownloads(getMaterial: () => Material, report: (message: string, kind: "error" | "info") => void): void {
  const bind = (id: string, run: (material: Material, progress: (p: number) => void) => Promise<void>) => {
    const button = document.getElementById(id) as HTMLButtonElement;
    const text = button.textContent ?? "";
    button.addEventListener("click", async () => {
      button.disabled = true;
      const progress = (p: number) => (button.textContent = `${text} ${Math.round(p * 100)}%`);
      try {
        await run(getMaterial(), progress);
      } catch (error) {
        if (!isAbort(error)) report(`${text}: ${messageOf(error)}`, "error");
      } finally {
        button.disabled = false;
        button.textContent = text;
      }
    });
  };

  bind("download-merl", async (material, progress) => {
    const request = create(TabulateRequestSchema, {
      material,
      grid: { case: "merl", value: {} },
      format: TableFormat.MERL,
    });
    save(await tabulate(request, "download MERL", progress), `${label(material)}.binary`, "application/octet-stream");
  });
  bind("download-exr", async (material, progress) => {
    const request = create(TabulateRequestSchema, {
      material,
      grid: { case: "inPlane", value: { thetaICount: 90, thetaOCount: 180 } },
      format: TableFormat.EXR,
    });
    save(await tabulate(request, "download EXR", progress), `${label(material)}-inplane.exr`, "image/x-exr");
  });
  bind("download-gltf", async (material) => {
    const request = create(FitMaterialRequestSchema, {
      material,
      target: FitTarget.GLTF_SHEEN,
      format: ExportFormat.GLB,
      name: label(material),
    });
    const reply = await timed("FitMaterial", "download glTF", () => client.fitMaterial(request));
    const fit = reply.fits[0];
    if (fit) report(`glTF sheen fit: ${(fit.error * 100).toFixed(1)}% off${fit.poorFit ? ` (${fit.poorFit})` : ""}`, "info");
    save([reply.file], `${label(material)}${reply.fileExtension || ".glb"}`, "model/gltf-binary");
  });
}

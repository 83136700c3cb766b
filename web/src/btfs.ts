// #btfs: the server's BTF assets (ListBtfs), a button each that puts the material on model `btf`, that asset.
import { client, messageOf } from "./api.js";
import { timed } from "./timings.js";

export async function listBtfs(list: HTMLElement, onPick: (asset: string) => void): Promise<void> {
  try {
    const reply = await timed("ListBtfs", "btfs", () => client.listBtfs({}));
    list.replaceChildren();
    if (reply.assets.length === 0) {
      const empty = document.createElement("p");
      empty.className = "hint";
      empty.textContent = "No BTF assets on this server yet (CreateBtf makes one from a woven material).";
      list.appendChild(empty);
    }
    for (const asset of reply.assets) {
      const button = document.createElement("button");
      button.type = "button";
      button.dataset.asset = asset.name;
      button.textContent = asset.name;
      button.title = `${asset.source}: ${asset.width}×${asset.height} texels, ${asset.components} components, ` +
        `${(Number(asset.bytes) / 2 ** 20).toFixed(1)} MiB`;
      button.addEventListener("click", () => onPick(asset.name));
      list.appendChild(button);
    }
  } catch (error) {
    list.textContent = `BTF assets unavailable: ${messageOf(error)}`;
  }
}

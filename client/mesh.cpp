// `loomlight mesh ...`: meshes stored on the server (docs/products.md "Meshes"): upload a glTF or OBJ file from
// this machine, list them, delete one. A render names a stored mesh (RenderRequest.mesh.name).
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <system_error>

#include "client/commands.h"
#include "client/progress.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

namespace fs = std::filesystem;

constexpr size_t kChunkBytes = size_t{1} << 20;  // per UploadMeshMessage.chunk

double mib(uint64_t bytes) { return static_cast<double>(bytes) / (1 << 20); }

v1::MeshFormat mesh_format(const ParsedOptions& options) {
  const std::string name = options.last("format").value_or("auto");
  if (name == "auto") return v1::MESH_FORMAT_AUTO;
  if (name == "glb") return v1::MESH_FORMAT_GLB;
  if (name == "gltf") return v1::MESH_FORMAT_GLTF;
  if (name == "obj") return v1::MESH_FORMAT_OBJ;
  throw UsageError("--format: expected auto, glb, gltf or obj, got '" + name + "'");
}

const char* format_name(v1::MeshFormat format) {
  switch (format) {
    case v1::MESH_FORMAT_GLB: return "glb";
    case v1::MESH_FORMAT_GLTF: return "gltf";
    case v1::MESH_FORMAT_OBJ: return "obj";
    default: return "?";
  }
}

void print_mesh(const v1::MeshInfo& mesh) {
  std::printf("%s: %s, %llu triangles, %llu vertices, %llu bytes\n", mesh.name().c_str(), format_name(mesh.format()),
              static_cast<unsigned long long>(mesh.triangles()), static_cast<unsigned long long>(mesh.vertices()),
              static_cast<unsigned long long>(mesh.bytes()));
  std::printf("  materials:");
  for (const std::string& m : mesh.materials()) std::printf(" %s", m.empty() ? "(none)" : m.c_str());
  std::printf("\n  normals %s, uvs %s, tangents %s\n", mesh.has_normals() ? "from the file" : "computed",
              mesh.has_uvs() ? "yes" : "none", mesh.has_tangents() ? "from the file" : "computed");
  if (mesh.bounds_min_size() == 3 && mesh.bounds_max_size() == 3)
    std::printf("  bounds (%.4g, %.4g, %.4g) to (%.4g, %.4g, %.4g); surface area %.4g; a uv unit spans %.4g\n",
                mesh.bounds_min(0), mesh.bounds_min(1), mesh.bounds_min(2), mesh.bounds_max(0), mesh.bounds_max(1),
                mesh.bounds_max(2), mesh.surface_area(), mesh.metres_per_uv());
}

int run_upload(const ParsedOptions& options) {
  const std::string path = options.positional[0];
  std::error_code ec;
  const uintmax_t size = fs::file_size(path, ec);
  std::ifstream in(path, std::ios::binary);
  if (ec || !in) throw UsageError("mesh upload: cannot read '" + path + "'");
  v1::UploadMeshHeader header;
  header.set_name(options.last("name").value_or(fs::path(path).stem().string()));
  header.set_format(mesh_format(options));
  header.set_size(size);
  ProgressBar progress("MiB chunks sent");
  const size_t chunks = static_cast<size_t>((size + kChunkBytes - 1) / kChunkBytes);
  uintmax_t sent = 0;
  v1::MeshInfo mesh;
  try {
    mesh = Client(options).upload_mesh(header, [&](std::string& chunk) {
      if (sent == size) return false;
      chunk.resize(static_cast<size_t>(std::min<uintmax_t>(kChunkBytes, size - sent)));
      if (!in.read(chunk.data(), static_cast<std::streamsize>(chunk.size())))
        throw std::runtime_error("mesh upload: '" + path + "' could not be read to its end (it changed?)");
      sent += chunk.size();
      progress.update(static_cast<size_t>((sent + kChunkBytes - 1) / kChunkBytes), chunks);
      return true;
    });
  } catch (...) {
    progress.end();
    throw;
  }
  progress.end();
  print_mesh(mesh);
  return 0;
}

int run_list(const ParsedOptions& options) {
  const v1::ListMeshesResponse list = Client(options).list_meshes();
  if (!options.positional.empty()) {
    for (const v1::MeshInfo& mesh : list.meshes())
      if (mesh.name() == options.positional[0]) {
        print_mesh(mesh);
        return 0;
      }
    throw std::runtime_error("no mesh named '" + options.positional[0] + "' (see `loomlight mesh list`)");
  }
  if (list.meshes().empty()) {
    std::printf("no meshes (0 MiB of %.2f MiB)\n", mib(list.max_bytes()));
    return 0;
  }
  int name_width = 4;
  for (const v1::MeshInfo& mesh : list.meshes()) name_width = std::max<int>(name_width, mesh.name().size());
  std::printf("%-*s  %-6s  %10s  %10s  %9s  %12s  %s\n", name_width, "NAME", "FORMAT", "TRIANGLES", "VERTICES",
              "MATERIALS", "BYTES", "UVS");
  uint64_t total = 0;
  for (const v1::MeshInfo& mesh : list.meshes()) {
    std::printf("%-*s  %-6s  %10llu  %10llu  %9d  %12llu  %s\n", name_width, mesh.name().c_str(),
                format_name(mesh.format()), static_cast<unsigned long long>(mesh.triangles()),
                static_cast<unsigned long long>(mesh.vertices()), mesh.materials_size(),
                static_cast<unsigned long long>(mesh.bytes()), mesh.has_uvs() ? "yes" : "no");
    total += mesh.bytes();
  }
  std::printf("%d meshes, %.2f MiB of %.2f MiB\n", list.meshes_size(), mib(total), mib(list.max_bytes()));
  return 0;
}

int run_delete(const ParsedOptions& options) {
  Client(options).delete_mesh(options.positional[0]);
  std::printf("deleted %s\n", options.positional[0].c_str());
  return 0;
}

const Command& upload_command() {
  static const Command command = {
      "mesh upload",
      "FILE [--name NAME] [--format auto|glb|gltf|obj]",
      "store a glTF 2.0 (.glb, .gltf with embedded buffers) or Wavefront OBJ mesh on the server",
      "Sends FILE's bytes in 1 MiB chunks; the server checks the mesh (a glTF's external uris are refused, an\n"
      "OBJ's material library is not read: its usemtl names are the materials) and stores it as NAME (default:\n"
      "the file's name without its extension; 1-64 of A-Za-z0-9_.-). Then the stored mesh's summary is printed.\n"
      "Example: loomlight mesh upload garment.glb --name shirt",
      {{"name", "NAME", "the name to store it under (default: FILE's stem)"},
       {"format", "auto|glb|gltf|obj", "the file's format (default auto: from its first bytes)"}},
      run_upload,
      1,
      1,
  };
  return command;
}

const Command& list_command() {
  static const Command command = {
      "mesh list",
      "[NAME]",
      "list the stored meshes, or show one",
      "Without NAME: one line per mesh (name, format, triangles, vertices, materials, bytes, whether it has\n"
      "texture coordinates) and the store's total. With NAME: that mesh's summary (its material names too).",
      {},
      run_list,
      0,
      1,
  };
  return command;
}

const Command& delete_command() {
  static const Command command = {
      "mesh delete", "NAME", "delete a stored mesh", "", {}, run_delete, 1, 1,
  };
  return command;
}

}  // namespace

const Command& mesh_command() {
  static const Command command = {
      "mesh",
      "COMMAND ARGUMENTS [options]",
      "upload, list and delete meshes stored on the server",
      "A stored mesh (glTF 2.0 or OBJ) is uploaded once and rendered by name (RenderRequest.mesh.name).",
      {},
      nullptr,
      0,
      0,
      {&upload_command(), &list_command(), &delete_command()},
  };
  return command;
}

}  // namespace loomlight::client

// The client's connection to a Loomlight server: channel setup, calls, and how failures are reported.
#pragma once

#include <chrono>
#include <functional>
#include <iosfwd>
#include <memory>
#include <stdexcept>
#include <string>

#include <grpcpp/grpcpp.h>

#include "client/cli.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "loomlight/v1/loomlight.grpc.pb.h"

namespace loomlight::client {

namespace v1 = loomlight::v1;

// A failed call. what() is "<STATUS_CODE_NAME>: <message>", the one format every command prints.
struct RpcError : std::runtime_error {
  explicit RpcError(const grpc::Status& status);
  grpc::StatusCode code;
};

// "INVALID_ARGUMENT" for grpc::StatusCode::INVALID_ARGUMENT, and so on.
const char* status_code_name(grpc::StatusCode code);

// "fp32" or "fp64".
const char* precision_name(v1::Precision precision);

// --server and --timeout, accepted before the command and by every command.
const OptionList& connection_options();

class Client {
 public:
  // Target from --server, else $LOOMLIGHT_SERVER, else 127.0.0.1:50051.
  explicit Client(const ParsedOptions& options);

  // grpc.health.v1.Health/Check of `service` ("" = the whole server).
  grpc::health::v1::HealthCheckResponse::ServingStatus health(const std::string& service);
  v1::ListModelsResponse list_models();
  v1::ListScenesResponse list_scenes();
  // Checks that the response holds one RGB triple per query before returning it.
  v1::EvaluateResponse evaluate(const v1::EvaluateRequest& request);
  // Checks that the response holds wi, pdf, weight and f for every query before returning it.
  v1::SampleResponse sample(const v1::SampleRequest& request);
  // Checks that an image came back with the size asked for.
  v1::TextureSliceResponse texture_slice(const v1::TextureSliceRequest& request);
  // Streams a table: `on_chunk` sees every chunk in order (its data are consecutive pieces of the file).
  // Throws RpcError when the call ends with an error, also after some chunks arrived.
  void tabulate(const v1::TabulateRequest& request, const std::function<void(const v1::TabulateChunk&)>& on_chunk);
  // Streams a render: `on_update` sees every progress update and, last, the one with the image.
  void render(const v1::RenderRequest& request, const std::function<void(const v1::RenderUpdate&)>& on_update);
  // Streams a yarn's fiber curves: `on_chunk` sees the summary first, then every chunk of curves in order.
  void yarn_geometry(const v1::YarnGeometryRequest& request,
                     const std::function<void(const v1::YarnGeometryChunk&)>& on_chunk);
  // Streams the making of a BTF asset: `on_progress` sees every update and, last, the one with the asset.
  void create_btf(const v1::CreateBtfRequest& request,
                  const std::function<void(const v1::CreateBtfProgress&)>& on_progress);
  // Uploads a BTF's images: the header, then one image per call of `next_image` until it returns false.
  // Returns the stored asset; throws RpcError when the server refuses, also part way through.
  v1::BtfAssetInfo upload_btf(const v1::UploadBtfHeader& header, const std::function<bool(v1::BtfImage&)>& next_image);
  v1::ListBtfsResponse list_btfs();
  void delete_btf(const std::string& name);
  // Uploads a mesh file: the header, then one chunk per call of `next_chunk` until it returns false. Returns the
  // stored mesh's description; throws RpcError when the server refuses, also part way through.
  v1::MeshInfo upload_mesh(const v1::UploadMeshHeader& header, const std::function<bool(std::string&)>& next_chunk);
  v1::ListMeshesResponse list_meshes();
  void delete_mesh(const std::string& name);
  // Checks that a file came back when a format was asked for.
  v1::FitMaterialResponse fit_material(const v1::FitMaterialRequest& request);

 private:
  void prepare(grpc::ClientContext& context) const;

  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::Loomlight::Stub> stub_;
  std::chrono::milliseconds timeout_;
};

// The server's timing and batching report of one Evaluate call, as one line (for --verbose).
void print_timing(std::ostream& out, const v1::EvaluateResponse& response, int queries);

}  // namespace loomlight::client

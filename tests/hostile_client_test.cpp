// What a hostile or careless client tried against a real server on loopback (issue 10), each reproducer
// kept: environment maps named by path, URL, device, FIFO, pseudo-format or decompression bomb are refused
// without decoding while other clients' work completes, and nothing outside the operator's directory can be
// probed; the material cache and unread streams keep the server's memory under a bound; bulk work goes behind
// interactive calls; health and SIGTERM behave as an operator expects; and issue 44's caps, stalls and
// permanent refusals.
#include <arpa/inet.h>
#include <fcntl.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <future>
#include <sstream>
#include <thread>
#include <tuple>

#include "grpc/health/v1/health.grpc.pb.h"
#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/server.h"
#include "server/models/accuracy.h"
#include "tests/testing.h"

namespace loomlight {
namespace {

using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

double SecondsSince(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

using testing::HdrBomb;

v1::RenderRequest SmallRender() {
  v1::RenderRequest r;
  r.mutable_material()->set_preset("linen_plain");
  r.set_scene(v1::SCENE_SPHERE);
  r.set_width(16);
  r.set_height(16);
  r.set_samples_per_pixel(1);
  r.set_format(v1::RENDER_FORMAT_EXR);
  return r;
}

struct Rendered {
  grpc::Status status;
  std::string image;
};

Rendered Render(v1::Loomlight::Stub& stub, const v1::RenderRequest& request, double timeout_s = 60) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() +
                       std::chrono::milliseconds(static_cast<int64_t>(timeout_s * 1000)));
  auto reader = stub.Render(&context, request);
  Rendered out;
  v1::RenderUpdate update;
  while (reader->Read(&update))
    if (!update.image().empty()) out.image = update.image();
  out.status = reader->Finish();
  return out;
}

grpc::Status Health(const std::string& address, grpc::health::v1::HealthCheckResponse::ServingStatus* status) {
  auto stub = grpc::health::v1::Health::NewStub(grpc::CreateChannel(address, grpc::InsecureChannelCredentials()));
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(2));
  grpc::health::v1::HealthCheckRequest request;
  grpc::health::v1::HealthCheckResponse response;
  const grpc::Status s = stub->Check(&context, request, &response);
  *status = response.status();
  return s;
}

// A texture slice of about a million queries: other clients' work that must complete meanwhile.
std::future<grpc::Status> StartSlice(v1::Loomlight::Stub& stub) {
  return std::async(std::launch::async, [&stub] {
    v1::TextureSliceRequest r;
    r.mutable_material()->set_preset("cotton_twill");
    for (float v : {0.0f, 0.6f, 0.8f}) r.add_wi(v);
    for (float v : {0.0f, -0.6f, 0.8f}) r.add_wo(v);
    r.set_width(512);
    r.set_height(512);
    r.set_samples_per_pixel(4);
    r.set_format(v1::IMAGE_FORMAT_RAW);
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    v1::TextureSliceResponse response;
    return stub.TextureSlice(&context, r, &response);
  });
}

// The operator's environment directory, with a good map and every kind of bad entry.
class EnvironmentDir {
 public:
  EnvironmentDir() : dir_(::testing::TempDir() + "/loomlight_env_" + std::to_string(getpid())) {
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    fs::copy_file(std::string(LOOMLIGHT_SOURCE_DIR) + "/deploy/environments/studio.hdr", dir_ + "/sky.hdr");
    mkfifo((dir_ + "/fifo.hdr").c_str(), 0600);
    {  // 1 GB, sparse: costs no disk, would cost a gigabyte to read
      const int fd = ::open((dir_ + "/huge.exr").c_str(), O_CREAT | O_WRONLY, 0600);
      EXPECT_EQ(ftruncate(fd, off_t{1} << 30), 0);
      ::close(fd);
    }
    std::ofstream(dir_ + "/bomb.hdr", std::ios::binary) << HdrBomb(100000, 100000);
    fs::create_symlink("/etc/passwd", dir_ + "/link.hdr");
    fs::create_symlink("/dev/zero", dir_ + "/zero.hdr");
    fs::create_symlink(dir_ + "/sky.hdr", dir_ + "/alias.hdr");
  }
  ~EnvironmentDir() { fs::remove_all(dir_); }
  const std::string& path() const { return dir_; }

 private:
  std::string dir_;
};

class HostileEnvironment : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new EnvironmentDir;
    server_ = new testing::ServerProcess({"--environment-dir", dir_->path()});
  }
  static void TearDownTestSuite() {
    delete server_;
    delete dir_;
  }
  static EnvironmentDir* dir_;
  static testing::ServerProcess* server_;
};
EnvironmentDir* HostileEnvironment::dir_ = nullptr;
testing::ServerProcess* HostileEnvironment::server_ = nullptr;

TEST_F(HostileEnvironment, BadMapsAreRefusedUndecodedWhileASliceCompletes) {
  ASSERT_GT(server_->port(), 0);
  auto stub = testing::Connect(server_->port());
  // A loopback listener: a URL handed to an image library would connect to it.
  const int listener = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ASSERT_EQ(bind(listener, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  ASSERT_EQ(listen(listener, 4), 0);
  socklen_t len = sizeof addr;
  getsockname(listener, reinterpret_cast<sockaddr*>(&addr), &len);
  const std::string url = "http://127.0.0.1:" + std::to_string(ntohs(addr.sin_port)) + "/sky.exr";

  auto slice = StartSlice(*stub);
  struct Case {
    const char* what;
    std::function<void(v1::RenderEnvironment*)> set;
    const char* field;
  };
  const std::string pseudo = "x.null?RES=8192x8192&CHANNELS=3&TYPE=float";
  const Case cases[] = {
      {"absolute path", [](auto* e) { e->set_path("/etc/passwd"); }, "environment.path"},
      {"pseudo-format path", [&](auto* e) { e->set_path(pseudo); }, "environment.path"},
      {"URL path", [&](auto* e) { e->set_path(url); }, "environment.path"},
      {"absolute name", [](auto* e) { e->set_name("/etc/shadow"); }, "environment.name"},
      {"dot-dot name", [](auto* e) { e->set_name("../sky.hdr"); }, "environment.name"},
      {"dot-dot", [](auto* e) { e->set_name(".."); }, "environment.name"},
      {"device", [](auto* e) { e->set_name("/dev/zero"); }, "environment.name"},
      {"pseudo-format name", [&](auto* e) { e->set_name(pseudo); }, "environment.name"},
      {"URL name", [&](auto* e) { e->set_name(url); }, "environment.name"},
      {"FIFO in the directory", [](auto* e) { e->set_name("fifo.hdr"); }, "environment.name"},
      {"1 GB sparse file", [](auto* e) { e->set_name("huge.exr"); }, "environment.name"},
      {"link out of the directory", [](auto* e) { e->set_name("link.hdr"); }, "environment.name"},
      {"link to /dev/zero", [](auto* e) { e->set_name("zero.hdr"); }, "environment.name"},
      {"header of 10^10 pixels", [](auto* e) { e->set_name("bomb.hdr"); }, "environment.name"},
      {"bytes of no format", [](auto* e) { e->set_data(std::string(1 << 20, '\0')); }, "environment.data"},
      {"sent header of 10^10 pixels", [](auto* e) { e->set_data(HdrBomb(100000, 100000)); }, "environment.data"},
      {"name and bytes", [](auto* e) { e->set_name("sky.hdr"); e->set_data(HdrBomb(4, 4)); }, "environment.data"},
  };
  for (const Case& c : cases) {
    v1::RenderRequest r = SmallRender();
    c.set(r.mutable_environment());
    const auto start = Clock::now();
    const Rendered result = Render(*stub, r);
    const double seconds = SecondsSince(start);
    EXPECT_EQ(result.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.what << ": " << result.status.error_message();
    EXPECT_EQ(result.status.error_message().rfind(std::string(c.field) + ":", 0), 0u)
        << c.what << ": " << result.status.error_message();
    // Reported, not asserted (a time): refused from the name, the header or the size, never decoded.
    std::printf("  %-28s refused in %.3f s: %s\n", c.what, seconds, result.status.error_message().c_str());
  }
  EXPECT_TRUE(slice.get().ok());
  sockaddr_in peer{};
  socklen_t peer_len = sizeof peer;
  EXPECT_LT(accept(listener, reinterpret_cast<sockaddr*>(&peer), &peer_len), 0) << "the server connected to " << url;
  close(listener);
  EXPECT_TRUE(server_->running());
}

TEST_F(HostileEnvironment, NothingOutsideTheDirectoryCanBeProbed) {
  auto stub = testing::Connect(server_->port());
  const auto message = [&](const std::function<void(v1::RenderEnvironment*)>& set) {
    v1::RenderRequest r = SmallRender();
    set(r.mutable_environment());
    return Render(*stub, r).status.error_message();
  };
  // An existing and a missing file outside: the same answer, which names neither.
  const std::string shadow = message([](auto* e) { e->set_name("/etc/shadow"); });
  EXPECT_EQ(shadow, message([](auto* e) { e->set_name("/etc/shadowX"); }));
  EXPECT_EQ(shadow.find("shadow"), std::string::npos) << shadow;
  EXPECT_EQ(message([](auto* e) { e->set_path("/etc/shadow"); }), message([](auto* e) { e->set_path("/etc/shadowX"); }));
  // Inside: a link to an existing file reads exactly as a name that is not there.
  std::string link = message([](auto* e) { e->set_name("link.hdr"); });
  std::string missing = message([](auto* e) { e->set_name("nope.hdr"); });
  link.replace(link.find("link.hdr"), 8, "NAME");
  missing.replace(missing.find("nope.hdr"), 8, "NAME");
  EXPECT_EQ(link, missing);
}

TEST_F(HostileEnvironment, NamedAndSentMapsLightTheSceneAlike) {
  auto stub = testing::Connect(server_->port());
  v1::ListModelsResponse models;
  {
    grpc::ClientContext context;
    ASSERT_TRUE(stub->ListModels(&context, v1::ListModelsRequest(), &models).ok());
  }
  // Listed: regular files within the byte cap; not the FIFO, the links or the 1 GB file.
  const std::vector<std::string> listed(models.environment_maps().begin(), models.environment_maps().end());
  EXPECT_EQ(listed, (std::vector<std::string>{"bomb.hdr", "sky.hdr"}));

  v1::RenderRequest named = SmallRender();
  named.set_seed(7);
  named.mutable_environment()->set_name("sky.hdr");
  v1::RenderRequest sent = named;
  sent.mutable_environment()->clear_name();
  sent.mutable_environment()->set_data(ReadFile(dir_->path() + "/sky.hdr"));
  v1::RenderRequest builtin = named;
  builtin.mutable_environment()->clear_name();
  const Rendered a = Render(*stub, named), b = Render(*stub, sent), c = Render(*stub, builtin);
  ASSERT_TRUE(a.status.ok()) << a.status.error_message();
  ASSERT_TRUE(b.status.ok()) << b.status.error_message();
  ASSERT_TRUE(c.status.ok()) << c.status.error_message();
  EXPECT_EQ(a.image, b.image);  // the same map, by name (cached after the first use) or by bytes
  EXPECT_NE(a.image, c.image);  // and not the built-in sky
  EXPECT_EQ(Render(*stub, named).image, a.image);  // from the cache: the same bytes
}

TEST(ShippedEnvironments, WorkOutOfTheBox) {
  testing::ServerProcess server({"--environment-dir", std::string(LOOMLIGHT_SOURCE_DIR) + "/deploy/environments"});
  auto stub = testing::Connect(server.port());
  for (const char* name : {"studio.hdr", "sunset.exr"}) {
    v1::RenderRequest r = SmallRender();
    r.set_width(96);
    r.set_height(64);
    r.set_samples_per_pixel(4);
    r.set_scene(v1::SCENE_CYLINDERS);
    r.set_format(v1::RENDER_FORMAT_PNG);
    r.mutable_environment()->set_name(name);
    const Rendered result = Render(*stub, r);
    ASSERT_TRUE(result.status.ok()) << name << ": " << result.status.error_message();
    const testing::DecodedImage image = testing::DecodeImage(result.image, "x.png");
    double mean = 0;
    for (float v : image.pixels) mean += v / image.pixels.size();
    EXPECT_GT(mean, 0.05) << name;  // lit, not black
    std::ofstream(::testing::TempDir() + "/shipped_" + std::string(name) + ".png", std::ios::binary) << result.image;
  }
}

// ---- Memory: the cache and unread streams (D4, D5) ----

TEST(BoundedMemory, UnknownFieldsNeverReachTheMaterialCache) {
  testing::ServerProcess server;
  auto stub = testing::Connect(server.port());
  const accuracy::Pairs pairs = accuracy::RandomPairs(1, 1);
  const auto evaluate = [&](int variant) {
    v1::EvaluateRequest r;
    r.mutable_material()->set_preset("velvet");
    // A different 4 MiB unknown field each time (field 999 is not in Material).
    r.mutable_material()->GetReflection()->MutableUnknownFields(r.mutable_material())->AddLengthDelimited(
        999, std::string(4 << 20, static_cast<char>('a' + variant % 26)) + std::to_string(variant));
    r.mutable_wi()->Add(pairs.wi.begin(), pairs.wi.end());
    r.mutable_wo()->Add(pairs.wo.begin(), pairs.wo.end());
    grpc::ClientContext context;
    v1::EvaluateResponse response;
    return stub->Evaluate(&context, r, &response);
  };
  // A first 100 settle the allocators (and a sanitizer build's quarantine of freed memory, 256 MB).
  const size_t start = server.RssBytes();
  for (int i = 0; i < 100; ++i) ASSERT_TRUE(evaluate(i).ok()) << i;
  const size_t before = server.RssBytes();
  for (int i = 100; i < 400; ++i) ASSERT_TRUE(evaluate(i).ok()) << i;
  const size_t after = server.RssBytes();
  std::printf("  RSS %.0f MB at start, %.0f MB after 100 and %.0f MB after 400 materials with distinct 4 MiB unknown "
              "fields\n", start / 1e6, before / 1e6, after / 1e6);
  EXPECT_LT(after, before + (size_t{128} << 20));  // 300 more: was +2.45 GB, never released
  EXPECT_LT(after, start + (size_t{512} << 20));
}

TEST(BoundedMemory, MaterialCacheIsBoundedInBytesAndKeyedOnTheResolvedMaterial) {
  models::MaterialCache cache(size_t{256} << 10);
  const models::Registry& registry = models::Registry::Global();
  std::shared_ptr<const models::PreparedMaterial> entry;
  // The preset, the same values given explicitly, and unknown fields: one entry.
  v1::Material preset;
  preset.set_preset("velvet");
  ASSERT_EQ(cache.Get(preset, registry, &entry), "");
  v1::Material spelled;
  spelled.set_model("microcylinder");
  const models::PresetSpec* spec = nullptr;
  const models::Model* model = registry.FindPreset("velvet", &spec);
  for (const auto& [name, values] : model->PresetValues(*spec)) {
    v1::Param* p = spelled.add_params();
    p->set_name(name);
    p->mutable_values()->Add(values.begin(), values.end());
  }
  ASSERT_EQ(cache.Get(spelled, registry, &entry), "");
  preset.GetReflection()->MutableUnknownFields(&preset)->AddVarint(777, 1);
  ASSERT_EQ(cache.Get(preset, registry, &entry), "");
  EXPECT_EQ(cache.entries(), 1u);
  // Thousands of distinct materials stay within the bytes.
  for (int i = 0; i < 3000; ++i) {
    v1::Material m;
    m.set_preset("velvet");
    v1::Param* p = m.add_params();
    p->set_name("tangent_samples");
    p->add_values(1 + i % 256);
    v1::Param* q = m.add_params();
    q->set_name("eta");
    q->add_values(1.2 + i * 1e-4);
    ASSERT_EQ(cache.Get(m, registry, &entry), "");
    ASSERT_LE(cache.bytes(), size_t{256} << 10);
  }
  EXPECT_LT(cache.entries(), 3000u);
  EXPECT_GT(cache.entries(), 10u);
}

// A material's sampling table (built on its first render or Sample call) counts in the cache's bytes once, and
// the cache stays within its bound as tables are built.
TEST(BoundedMemory, MaterialCacheCountsSamplingTables) {
  constexpr size_t kCapacity = size_t{16} << 20;  // room for a sampling table of up to 4x today's (0.7 MiB)
  models::MaterialCache cache(kCapacity);
  const models::Registry& registry = models::Registry::Global();
  std::shared_ptr<const models::PreparedMaterial> entry;
  v1::Material m;
  m.set_preset("cotton_twill");
  ASSERT_EQ(cache.Get(m, registry, &entry), "");
  const size_t before = cache.bytes();
  cache.ChargeSampler(*entry);  // not built yet: nothing to count
  EXPECT_EQ(cache.bytes(), before);
  const size_t table = entry->Sampler().bytes();
  EXPECT_GT(table, size_t{100} << 10);
  cache.ChargeSampler(*entry);
  cache.ChargeSampler(*entry);  // counted once
  // The entry and its request-bytes alias both hold the table.
  EXPECT_GE(cache.bytes(), before + table);
  EXPECT_LE(cache.bytes(), before + 2 * table);
  for (int i = 0; i < 12; ++i) {
    v1::Material other;
    other.set_preset("cotton_twill");
    v1::Param* p = other.add_params();
    p->set_name("eta");
    p->add_values(1.3 + 0.01 * i);
    ASSERT_EQ(cache.Get(other, registry, &entry), "");
    entry->Sampler();
    cache.ChargeSampler(*entry);
    ASSERT_LE(cache.bytes(), kCapacity);
  }
  EXPECT_LT(cache.entries(), 13u);
}

using testing::BigTable;

// p50 and p99 of sequential 64-query Evaluate calls while `keep_going`.
std::pair<double, double> EvaluateLatency(v1::Loomlight::Stub& stub, int calls, int* failures) {
  std::vector<double> seconds;
  const accuracy::Pairs pairs = accuracy::RandomPairs(64, 3);
  for (int i = 0; i < calls; ++i) {
    v1::EvaluateRequest r;
    r.mutable_material()->set_preset("linen_plain");
    r.mutable_wi()->Add(pairs.wi.begin(), pairs.wi.end());
    r.mutable_wo()->Add(pairs.wo.begin(), pairs.wo.end());
    grpc::ClientContext context;
    v1::EvaluateResponse response;
    const auto start = Clock::now();
    if (!stub.Evaluate(&context, r, &response).ok()) ++*failures;
    seconds.push_back(SecondsSince(start));
  }
  std::sort(seconds.begin(), seconds.end());
  return {seconds[seconds.size() / 2], seconds[std::min(seconds.size() - 1, seconds.size() * 99 / 100)]};
}

TEST(BoundedMemory, UnreadStreamsAreAdmittedUpToTheLimitAndHoldLittle) {
  testing::ServerProcess server({"--trusted-proxy", "127.0.0.1"});  // the clients' X-Forwarded-For, below
  auto stub = testing::Connect(server.port());
  const size_t before = server.RssBytes();
  struct Stream {
    grpc::ClientContext context;
    std::unique_ptr<grpc::ClientReader<v1::TabulateChunk>> reader;
    int client = 0;
  };
  // Three clients, each its own connection, 40 streams each. A host is one client, so each names its own
  // address as a trusted proxy would (X-Forwarded-For).
  std::vector<std::unique_ptr<v1::Loomlight::Stub>> clients;
  for (int c = 0; c < 3; ++c) {
    grpc::ChannelArguments args;
    args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
    args.SetInt("loomlight.test.client", c);
    clients.push_back(v1::Loomlight::NewStub(grpc::CreateCustomChannel(
        "127.0.0.1:" + std::to_string(server.port()), grpc::InsecureChannelCredentials(), args)));
  }
  std::vector<std::unique_ptr<Stream>> streams;
  for (int i = 0; i < 120; ++i) {
    auto s = std::make_unique<Stream>();
    s->client = i % 3;
    s->context.AddMetadata("x-forwarded-for", "192.0.2." + std::to_string(s->client + 1));
    s->reader = clients[static_cast<size_t>(s->client)]->Tabulate(&s->context, BigTable());
    streams.push_back(std::move(s));
  }
  std::this_thread::sleep_for(std::chrono::seconds(8));  // the admitted ones fill their buffers and stall
  const size_t loaded = server.RssBytes();
  int failures = 0;
  const auto [p50, p99] = EvaluateLatency(*stub, 50, &failures);
  // Read one message of each: the refused ones end at once with RESOURCE_EXHAUSTED.
  int refused = 0, admitted = 0, admitted_per_client[3] = {0, 0, 0};
  for (auto& s : streams) {
    v1::TabulateChunk chunk;
    if (s->reader->Read(&chunk)) {
      ++admitted;
      ++admitted_per_client[s->client];
      s->context.TryCancel();
    } else {
      const grpc::Status status = s->reader->Finish();
      EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << status.error_message();
      ++refused;
    }
  }
  std::printf("  120 unread 33.5M-cell tabulations: %d admitted, %d refused; RSS %.0f MB -> %.0f MB; "
              "Evaluate (64 queries) p50 %.1f ms, p99 %.1f ms, %d failed\n",
              admitted, refused, before / 1e6, loaded / 1e6, p50 * 1e3, p99 * 1e3, failures);
  EXPECT_EQ(admitted, 16);  // --max-long-calls' default
  EXPECT_EQ(refused, 104);
  for (int c = 0; c < 3; ++c) EXPECT_LE(admitted_per_client[c], 8) << c;  // --max-long-calls-per-client's default
  EXPECT_LT(loaded, before + (size_t{1} << 30));  // was 4.3 GB for 120 streams
  EXPECT_EQ(failures, 0);  // the latencies above are reported, not asserted (times)
  for (auto& s : streams) s->context.TryCancel();
  streams.clear();
}

TEST(BoundedMemory, InteractiveCallsGoAheadOfBulkWork) {
  testing::ServerProcess server;
  auto stub = testing::Connect(server.port());
  int idle_failures = 0;
  const auto idle = EvaluateLatency(*stub, 30, &idle_failures);
  // Eight tabulations read as fast as they come: the device is never idle.
  std::atomic<bool> stop{false};
  std::vector<std::thread> readers;
  std::atomic<uint64_t> bytes{0};
  std::vector<std::unique_ptr<grpc::ClientContext>> contexts;
  for (int i = 0; i < 8; ++i) contexts.push_back(std::make_unique<grpc::ClientContext>());
  for (int i = 0; i < 8; ++i)
    readers.emplace_back([&, i] {
      auto reader = stub->Tabulate(contexts[i].get(), BigTable());
      v1::TabulateChunk chunk;
      while (!stop && reader->Read(&chunk)) bytes += chunk.data().size();
      contexts[i]->TryCancel();
      reader->Finish();
    });
  std::this_thread::sleep_for(std::chrono::seconds(2));
  int failures = 0;
  const auto [p50, p99] = EvaluateLatency(*stub, 50, &failures);
  stop = true;
  for (auto& c : contexts) c->TryCancel();
  for (auto& t : readers) t.join();
  std::printf("  Evaluate (64 queries) idle p50 %.1f ms p99 %.1f ms; beside 8 busy tabulations (%.0f MB streamed) "
              "p50 %.1f ms p99 %.1f ms\n",
              idle.first * 1e3, idle.second * 1e3, bytes / 1e6, p50 * 1e3, p99 * 1e3);
  EXPECT_GT(bytes.load(), 0u);
  // The latencies are reported, not asserted (times): an interactive call waits for at most the one bulk launch
  // running, which batcher_test's InteractiveJobsLaunchBeforeQueuedBulkJobs asserts as an order.
  EXPECT_EQ(failures, 0);
}

// ---- Health and shutdown (D2, D6) ----

TEST(Shutdown, SigtermDrainsALongTabulation) {
  testing::ServerProcess server({"--shutdown-grace", "60"});
  auto stub = testing::Connect(server.port());
  v1::TabulateRequest r;
  r.mutable_material()->set_preset("velvet");
  r.mutable_merl()->set_phi_h_samples(4);  // 5.8 M queries: seconds of work
  r.set_format(v1::TABLE_FORMAT_RAW);
  grpc::ClientContext context;
  auto reader = stub->Tabulate(&context, r);
  v1::TabulateChunk chunk;
  ASSERT_TRUE(reader->Read(&chunk));
  uint64_t bytes = chunk.data().size(), total = chunk.cells_total(), done = chunk.cells_done();
  ASSERT_LT(done, total);
  kill(server.pid(), SIGTERM);
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  // Draining: health says NOT_SERVING and no new call is taken.
  grpc::health::v1::HealthCheckResponse::ServingStatus health;
  const grpc::Status h = Health(server.address(), &health);
  EXPECT_TRUE(!h.ok() || health == grpc::health::v1::HealthCheckResponse::NOT_SERVING);
  {
    grpc::ClientContext c;
    v1::ListModelsResponse models;
    c.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(2));
    EXPECT_FALSE(stub->ListModels(&c, v1::ListModelsRequest(), &models).ok());
  }
  while (reader->Read(&chunk)) {
    bytes += chunk.data().size();
    done = chunk.cells_done();
  }
  const grpc::Status status = reader->Finish();
  EXPECT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(done, total);
  EXPECT_EQ(bytes, 40 + total * 12);  // the RAW header and every cell
  EXPECT_EQ(server.Terminate(std::chrono::seconds(10)), 0);
}

TEST(Shutdown, GraceRunsOutThenCallsAreCancelledAndTheProcessExits) {
  testing::ServerProcess server({"--shutdown-grace", "1"});
  auto stub = testing::Connect(server.port());
  grpc::ClientContext context;
  auto reader = stub->Tabulate(&context, BigTable());
  v1::TabulateChunk chunk;
  ASSERT_TRUE(reader->Read(&chunk));
  const auto start = Clock::now();
  kill(server.pid(), SIGTERM);
  while (reader->Read(&chunk)) {
  }
  const grpc::Status status = reader->Finish();
  EXPECT_FALSE(status.ok());
  EXPECT_EQ(server.Terminate(std::chrono::seconds(10)), 0);
  const double seconds = SecondsSince(start);
  std::printf("  grace 1 s: stream ended with %d (%s); process exited after %.2f s\n", status.error_code(),
              status.error_message().c_str(), seconds);  // reported; the exit itself is what Terminate checks
}

TEST(Health, NotServingWhileALaunchIsStuckAndServingAfter) {
  testing::ServerProcess server({"--stall-seconds", "1"});
  auto stub = testing::Connect(server.port());
  // One launch of 2^20 velvet queries at 256 tangent samples in double: several seconds on one launch.
  v1::EvaluateRequest r;
  r.mutable_material()->set_preset("velvet");
  v1::Param* t = r.mutable_material()->add_params();
  t->set_name("tangent_samples");
  t->add_values(256);
  r.set_precision(v1::PRECISION_FP64);
  const accuracy::Pairs pairs = accuracy::RandomPairs(size_t{1} << 20, 5);
  r.mutable_wi()->Add(pairs.wi.begin(), pairs.wi.end());
  r.mutable_wo()->Add(pairs.wo.begin(), pairs.wo.end());
  auto call = std::async(std::launch::async, [&] {
    grpc::ClientContext context;
    v1::EvaluateResponse response;
    return stub->Evaluate(&context, r, &response);
  });
  bool saw_not_serving = false, refused_meanwhile = false;
  while (call.wait_for(std::chrono::milliseconds(100)) != std::future_status::ready) {
    grpc::health::v1::HealthCheckResponse::ServingStatus health;
    if (Health(server.address(), &health).ok() && health == grpc::health::v1::HealthCheckResponse::NOT_SERVING &&
        !saw_not_serving) {
      saw_not_serving = true;
      grpc::ClientContext c;
      v1::ListModelsResponse models;
      refused_meanwhile = stub->ListModels(&c, v1::ListModelsRequest(), &models).error_code() ==
                          grpc::StatusCode::UNAVAILABLE;
    }
  }
  const auto finished = Clock::now();
  EXPECT_TRUE(call.get().ok());
  EXPECT_TRUE(saw_not_serving);
  EXPECT_TRUE(refused_meanwhile);
  grpc::health::v1::HealthCheckResponse::ServingStatus health = grpc::health::v1::HealthCheckResponse::UNKNOWN;
  while (SecondsSince(finished) < 60 &&  // a guard against a hang, not a bound
         (!Health(server.address(), &health).ok() || health != grpc::health::v1::HealthCheckResponse::SERVING))
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_EQ(health, grpc::health::v1::HealthCheckResponse::SERVING);
}

// ---- Metrics: a passed deadline is a DEADLINE_EXCEEDED ----

TEST(Metrics, AStreamWhoseDeadlinePassedCountsAsDeadlineExceeded) {
  api::ServerOptions options;
  options.metrics_address = "127.0.0.1:0";
  auto server = testing::StartInProcessServer(options);
  ASSERT_NE(server, nullptr);
  auto stub = testing::Connect(server->port());
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::milliseconds(500));
  auto reader = stub->Tabulate(&context, BigTable());
  v1::TabulateChunk chunk;
  while (reader->Read(&chunk)) {
  }
  EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
  std::string text;
  for (int i = 0; i < 50 && text.find("rpc=\"Tabulate\"") == std::string::npos; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    text = testing::HttpGet(server->metrics_port(), "/metrics");
  }
  EXPECT_NE(text.find("loomlight_calls_total{code=\"DEADLINE_EXCEEDED\",rpc=\"Tabulate\"} 1"), std::string::npos)
      << text;
  EXPECT_EQ(text.find("loomlight_calls_total{code=\"CANCELLED\",rpc=\"Tabulate\"}"), std::string::npos);
  // The admission resources are exported too (sampled by the watchdog).
  EXPECT_NE(text.find("loomlight_resource{name=\"long_calls_limit\"} 16"), std::string::npos) << text;
  EXPECT_NE(text.find("loomlight_resource{name=\"memory_bytes_limit\"} 2147483648"), std::string::npos);
  EXPECT_NE(text.find("loomlight_resource{name=\"serving\"} 1"), std::string::npos);
}

// ---- No call holds a slot or budget forever (issue 44, item 2) ----

// Waits until `done()` or `guard` passes (a hang guard, not a speed bound: what is waited for takes milliseconds).
bool WaitFor(const std::function<bool()>& done, std::chrono::seconds guard = std::chrono::seconds(60)) {
  const auto until = Clock::now() + guard;
  while (!done()) {
    if (Clock::now() > until) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return true;
}

// The count of loomlight_calls_total{code, rpc} in the server's metrics ("" when not there yet).
std::string CallCount(int metrics_port, const std::string& code, const std::string& rpc) {
  const std::string text = testing::HttpGet(metrics_port, "/metrics");
  const std::string key = "loomlight_calls_total{code=\"" + code + "\",rpc=\"" + rpc + "\"} ";
  const size_t at = text.find(key);
  if (at == std::string::npos) return "";
  return text.substr(at + key.size(), text.find('\n', at) - at - key.size());
}

v1::TabulateRequest SmallTable() {
  v1::TabulateRequest r;
  r.mutable_material()->set_preset("velvet");
  r.mutable_in_plane()->set_theta_i_count(4);
  r.mutable_in_plane()->set_theta_o_count(4);
  r.set_format(v1::TABLE_FORMAT_RAW);
  return r;
}

grpc::Status TabulateAll(v1::Loomlight::Stub& stub, const v1::TabulateRequest& request, uint64_t* cells_done = nullptr,
                         uint64_t* cells_total = nullptr, bool deadline = true) {
  grpc::ClientContext context;
  if (deadline) context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
  auto reader = stub.Tabulate(&context, request);
  v1::TabulateChunk chunk;
  while (reader->Read(&chunk)) {
    if (cells_done) *cells_done = chunk.cells_done();
    if (cells_total) *cells_total = chunk.cells_total();
  }
  return reader->Finish();
}

// A Tabulate call without a deadline (gRPC's default) ran until its 33.5 M cells were done, holding the only
// long-call slot all along; now the bulk cap ends it, saying so, and the next call gets the slot.
TEST(CallCaps, ABulkCallWithoutADeadlineIsEndedByTheCapAndTheNextCallGetsItsSlot) {
  api::ServerOptions options;
  options.limits.max_long_running_calls = 1;
  options.call_caps.bulk = std::chrono::seconds(1);
  auto server = testing::StartInProcessServer(options);
  ASSERT_NE(server, nullptr);
  auto stub = testing::Connect(server->port());
  const size_t idle_bytes = server->memory_in_use();
  std::atomic<bool> started{false};
  auto first = std::async(std::launch::async, [&] {
    grpc::ClientContext context;  // no deadline
    auto reader = stub->Tabulate(&context, BigTable());
    v1::TabulateChunk chunk;
    uint64_t done = 0, total = 0;
    while (reader->Read(&chunk)) {  // read as fast as it comes: nothing stalls but the work's length
      started = true;
      done = chunk.cells_done();
      total = chunk.cells_total();
    }
    const grpc::Status status = reader->Finish();
    return std::make_tuple(status, done, total);
  });
  ASSERT_TRUE(WaitFor([&] { return started.load(); }));
  // Meanwhile the slot is the first call's.
  EXPECT_EQ(TabulateAll(*stub, SmallTable()).error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  const auto [status, done, total] = first.get();
  std::printf("  a deadline-less 33.5 M-cell Tabulate under a 1 s bulk cap ended %s after %llu of %llu cells: %s\n",
              status.ok() ? "OK" : "with an error", static_cast<unsigned long long>(done),
              static_cast<unsigned long long>(total), status.error_message().c_str());
  EXPECT_EQ(status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << status.error_message();
  EXPECT_NE(status.error_message().find("--max-call-seconds"), std::string::npos) << status.error_message();
  EXPECT_LT(done, total);
  // Its slot and bytes are given back, and the next call is admitted.
  EXPECT_EQ(server->long_calls_in_use(), 0u);
  EXPECT_TRUE(WaitFor([&] { return server->memory_in_use() == idle_bytes; })) << server->memory_in_use();
  const grpc::Status next = TabulateAll(*stub, SmallTable());
  EXPECT_TRUE(next.ok()) << next.error_message();
}

// The interactive cap applies to interactive calls: an Evaluate without a deadline, queued behind a 3 s batch
// delay, ends at its launch with the cap's DEADLINE_EXCEEDED instead of running, and its bytes are released.
TEST(CallCaps, AnInteractiveCallWithoutADeadlineGetsTheInteractiveCap) {
  api::ServerOptions options;
  options.call_caps.interactive = std::chrono::seconds(1);
  options.batcher.interactive.max_queue_delay = std::chrono::seconds(3);
  auto server = testing::StartInProcessServer(options);
  ASSERT_NE(server, nullptr);
  auto stub = testing::Connect(server->port());
  const size_t idle_bytes = server->memory_in_use();
  const accuracy::Pairs pairs = accuracy::RandomPairs(8192, 9);  // over the inline launch's 4,096: queued
  v1::EvaluateRequest r;
  r.mutable_material()->set_preset("linen_plain");
  r.mutable_wi()->Add(pairs.wi.begin(), pairs.wi.end());
  r.mutable_wo()->Add(pairs.wo.begin(), pairs.wo.end());
  grpc::ClientContext context;  // no deadline
  v1::EvaluateResponse response;
  const grpc::Status status = stub->Evaluate(&context, r, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << status.error_message();
  EXPECT_NE(status.error_message().find("interactive calls, 1 s (--max-call-seconds)"), std::string::npos)
      << status.error_message();
  EXPECT_TRUE(WaitFor([&] { return server->memory_in_use() == idle_bytes; })) << server->memory_in_use();
}

// A client that starts a tabulation and reads nothing held its long-call slot and the bytes of its buffers for as
// long as it kept the connection; now the write it leaves in flight is cut off after --stall-write-seconds.
TEST(StalledStreams, AStreamNobodyReadsIsCancelledAndItsSlotAndMemoryReleased) {
  api::ServerOptions options;
  options.limits.max_long_running_calls = 1;
  options.stall_write_timeout = std::chrono::seconds(1);
  options.metrics_address = "127.0.0.1:0";
  auto server = testing::StartInProcessServer(options);
  ASSERT_NE(server, nullptr);
  auto stub = testing::Connect(server->port());
  const size_t idle_bytes = server->memory_in_use();
  grpc::ClientContext context;  // no deadline, and nothing read after the first chunk
  auto reader = stub->Tabulate(&context, BigTable());
  v1::TabulateChunk chunk;
  ASSERT_TRUE(reader->Read(&chunk));
  const size_t held = server->memory_in_use() - idle_bytes;
  EXPECT_GT(held, 0u);
  EXPECT_EQ(server->long_calls_in_use(), 1u);
  // The server's writes fill the flow-control windows and wait; the watchdog cancels the call.
  EXPECT_TRUE(WaitFor([&] { return CallCount(server->metrics_port(), "DEADLINE_EXCEEDED", "Tabulate") == "1"; }));
  EXPECT_EQ(server->long_calls_in_use(), 0u);
  EXPECT_TRUE(WaitFor([&] { return server->memory_in_use() == idle_bytes; })) << server->memory_in_use();
  std::printf("  an unread 33.5 M-cell Tabulate held %.1f MiB and the only long-call slot until cut off\n",
              held / 1048576.0);
  // The next call gets the slot; the stalled client finds its stream cancelled once it reads again.
  const grpc::Status next = TabulateAll(*stub, SmallTable());
  EXPECT_TRUE(next.ok()) << next.error_message();
  while (reader->Read(&chunk)) {
  }
  EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::CANCELLED);
  // A client that reads, however slowly the server's work goes between writes, is not cut off.
  EXPECT_TRUE(TabulateAll(*stub, SmallTable()).ok());
}

// Larger than the whole memory budget is a permanent refusal: FAILED_PRECONDITION (gRPC's guide: do not retry
// until the system's state is fixed), checked before a slot is taken, so a busy server does not answer it
// "retry later"; what does not fit now is still RESOURCE_EXHAUSTED.
TEST(PermanentRefusal, MoreThanTheWholeBudgetIsFailedPreconditionAndNotRetryLater) {
  batching::Budget memory(100), slots(1);
  api::Admission busy, a, b, c;
  ASSERT_TRUE(api::Admit(&memory, &slots, 60, &busy, "").ok());  // the only slot and 60 of 100 bytes in use
  const grpc::Status too_big = api::Admit(&memory, &slots, 101, &a, "");
  EXPECT_EQ(too_big.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << too_big.error_message();
  EXPECT_EQ(too_big.error_message().find("retry"), std::string::npos) << too_big.error_message();
  const grpc::Status later = api::Admit(&memory, nullptr, 50, &b, "");  // fits the budget, not what is free now
  EXPECT_EQ(later.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << later.error_message();
  EXPECT_NE(later.error_message().find("retry later"), std::string::npos) << later.error_message();
  EXPECT_EQ(api::Admit(&memory, &slots, 10, &c, "").error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);  // the slot
  EXPECT_EQ(memory.in_use(), 60u);
  EXPECT_EQ(slots.in_use(), 1u);
  // A call growing past the whole budget mid-way is told the same.
  EXPECT_EQ(api::MemoryRefusal(memory, 60, 41, "x").error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_EQ(api::MemoryRefusal(memory, 60, 40, "x").error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
}

// A tabulation larger than a server's whole budget: the server answers FAILED_PRECONDITION, and `loomlight batch`
// gives up on the job after its one attempt (it retried RESOURCE_EXHAUSTED four more times).
TEST(PermanentRefusal, TheBatchClientDoesNotRetryARequestLargerThanTheWholeBudget) {
  api::ServerOptions options;
  options.limits.memory_budget_bytes = size_t{1} << 20;
  options.metrics_address = "127.0.0.1:0";
  auto server = testing::StartInProcessServer(options);
  ASSERT_NE(server, nullptr);
  auto stub = testing::Connect(server->port());
  const grpc::Status direct = TabulateAll(*stub, BigTable());
  EXPECT_EQ(direct.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << direct.error_message();
  EXPECT_NE(direct.error_message().find("whole memory budget (1 MiB)"), std::string::npos) << direct.error_message();

  const std::string dir = ::testing::TempDir() + "/loomlight_refusal_" + std::to_string(getpid());
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::ofstream(dir + "/jobs.csv") << "id,kind,out,options\nbig,tab," << dir << "/big.binary,--preset velvet\n";
  std::string out;
  EXPECT_EQ(testing::RunClient(server->port(),
                               "batch --csv " + dir + "/jobs.csv --retries 4 --backoff 0 --log " + dir + "/jobs.log",
                               &out),
            1)
      << out;
  const std::string log = ReadFile(dir + "/jobs.log");
  EXPECT_NE(log.find("big,tab,failed,1,"), std::string::npos) << log;  // one attempt
  EXPECT_NE(log.find("FAILED_PRECONDITION"), std::string::npos) << log;
  EXPECT_FALSE(fs::exists(dir + "/big.binary"));
  // The server saw the direct call and the batch's one attempt, nothing more.
  EXPECT_TRUE(WaitFor([&] { return CallCount(server->metrics_port(), "FAILED_PRECONDITION", "Tabulate") == "2"; }))
      << CallCount(server->metrics_port(), "FAILED_PRECONDITION", "Tabulate");
  EXPECT_EQ(CallCount(server->metrics_port(), "RESOURCE_EXHAUSTED", "Tabulate"), "");
  fs::remove_all(dir);
}

}  // namespace
}  // namespace loomlight

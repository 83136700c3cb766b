// One hostile client for the soak (issue 44): beside the honest clients it cycles through the attacks
// tests/hostile_client_test.cpp and tests/access_test.cpp reproduce one at a time, from one address of its own
// (X-Forwarded-For through the server's trusted proxy), and checks each is answered with the refusal it deserves.
// The soak then asserts the honest clients saw no error, the server's memory levelled off and it still serves.
#pragma once

#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>

#include <atomic>
#include <chrono>
#include <functional>
#include <memory>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "grpc/health/v1/health.grpc.pb.h"
#include "loomlight/v1/loomlight.grpc.pb.h"
#include "server/api/service.h"
#include "tests/testing.h"

namespace loomlight::testing {

class HostileClient {
 public:
  // The server must run with --trusted-proxy 127.0.0.1 (the address is forwarded) and --stall-write-seconds
  // well under kUnreadSeconds (it must cut the unread stream before this client reads it).
  // `count` is called once per attack: with "" when it got the refusal it deserves, else with what it got.
  HostileClient(const std::string& address, std::string forwarded_for, std::function<void(const std::string&)> count)
      : target_(address),
        channel_(OwnChannel(address)),
        stub_(v1::Loomlight::NewStub(channel_)),
        forwarded_for_(std::move(forwarded_for)),
        count_(std::move(count)) {}

  static constexpr int kUnreadSeconds = 30;

  void Run(const std::atomic<bool>& stop) {
    for (int round = 0; !stop.load(); ++round) {
      FinishUnreadStream(false);
      switch (round % 6) {
        case 0: WifThatRepeatsIndices(); break;
        case 1: MadeUpMethod(round); break;
        case 2: StartUnreadStream(); break;
        case 3: EnvironmentBomb(); break;
        case 4: BurstOfLongCalls(); break;
        default: WatchFlood(); break;
      }
    }
    FinishUnreadStream(true);
  }

 private:
  void Prepare(grpc::ClientContext* context, int seconds) {
    if (seconds > 0) context->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(seconds));
    context->set_wait_for_ready(true);
    context->AddMetadata("x-forwarded-for", forwarded_for_);
  }

  // An answer otherwise than deserved: a crash's UNAVAILABLE, an INTERNAL, an OK where a refusal is due.
  void Expect(const char* attack, const grpc::Status& status, std::set<grpc::StatusCode> deserved) {
    count_(deserved.count(status.error_code()) ? ""
                                                : std::string(attack) + ": code " + std::to_string(status.error_code()) +
                                                      ": " + status.error_message().substr(0, 200));
  }

  // The draft that once took gigabytes: a tie-up row repeating one shaft and picks pressing one treadle as often.
  void WifThatRepeatsIndices() {
    static const std::string draft = [] {
      std::string text =
          "[WIF]\nVersion=1.1\n[CONTENTS]\nWEAVING=yes\nTHREADING=yes\nTIEUP=yes\nTREADLING=yes\n[WEAVING]\n"
          "Shafts=4\nTreadles=1\n[THREADING]\n1=1\n2=2\n3=3\n4=4\n[TIEUP]\n1=1";
      for (int i = 0; i < 100000; ++i) text += ",1";
      text += "\n[TREADLING]\n";
      for (int p = 1; p <= 256; ++p) {
        text += std::to_string(p) + "=1";
        for (int i = 0; i < 1400; ++i) text += ",1";
        text += "\n";
      }
      return text;
    }();
    v1::EvaluateRequest r;
    r.mutable_material()->set_preset("cotton_twill");
    v1::Param* wif = r.mutable_material()->add_params();
    wif->set_name("pattern.wif");
    wif->set_text(draft);
    for (float v : {0.0f, 0.0f, 1.0f}) r.add_wi(v), r.add_wo(v);
    grpc::ClientContext context;
    Prepare(&context, 60);
    v1::EvaluateResponse response;
    Expect("WIF repeating indices", stub_->Evaluate(&context, r, &response), {grpc::StatusCode::INVALID_ARGUMENT});
  }

  // A method the server does not have, a new name each time (the metrics keep one "unknown" label).
  void MadeUpMethod(int round) {
    grpc::GenericStub generic(channel_);
    grpc::ClientContext context;
    Prepare(&context, 30);
    grpc::CompletionQueue queue;
    grpc::Slice empty("", 0);
    grpc::ByteBuffer request(&empty, 1), reply;
    auto call = generic.PrepareUnaryCall(&context, "/loomlight.v1.Loomlight/MadeUp" + std::to_string(round), request,
                                         &queue);
    call->StartCall();
    grpc::Status status;
    call->Finish(&reply, &status, reinterpret_cast<void*>(1));
    void* tag = nullptr;
    bool ok = false;
    queue.Next(&tag, &ok);
    Expect("made-up method", status, {grpc::StatusCode::UNIMPLEMENTED});
  }

  // A 33.5 M-cell table, no deadline, not read for kUnreadSeconds while the other attacks go on: the server
  // cancels it once its write has waited --stall-write-seconds (or refuses it a slot while this client holds its
  // share). Then what the transport buffered is read, and the end must be the server's.
  void StartUnreadStream() {
    if (unread_) return;
    unread_ = std::make_unique<Unread>();
    // linen_plain, a cheap model, so its first megabytes fill the flow-control window at once even beside the
    // soak's load: velvet's slower table once had not filled it when this client began to read, and completed.
    v1::TabulateRequest r = BigTable();
    r.mutable_material()->set_preset("linen_plain");
    Prepare(&unread_->context, 0);
    unread_->reader = stub_->Tabulate(&unread_->context, r);
    unread_->started = std::chrono::steady_clock::now();
  }

  // Reads the unread stream to its end once kUnreadSeconds have passed (at once when the soak ends: then the
  // stream is cancelled here, and only an end the server chose is judged).
  void FinishUnreadStream(bool soak_ended) {
    if (!unread_) return;
    if (!soak_ended && std::chrono::steady_clock::now() - unread_->started < std::chrono::seconds(kUnreadSeconds))
      return;
    const bool waited = std::chrono::steady_clock::now() - unread_->started >= std::chrono::seconds(kUnreadSeconds);
    if (!waited) unread_->context.TryCancel();
    v1::TabulateChunk chunk;
    while (unread_->reader->Read(&chunk)) {
    }
    const grpc::Status status = unread_->reader->Finish();
    unread_.reset();
    if (!waited && status.error_code() == grpc::StatusCode::CANCELLED) return;
    Expect("stream nobody reads", status,
           {grpc::StatusCode::CANCELLED, grpc::StatusCode::DEADLINE_EXCEEDED, grpc::StatusCode::RESOURCE_EXHAUSTED});
  }

  // A Radiance header of 10^10 pixels sent as the environment's bytes.
  void EnvironmentBomb() {
    v1::RenderRequest r;
    r.mutable_material()->set_preset("linen_plain");
    r.set_scene(v1::SCENE_SPHERE);
    r.set_width(16);
    r.set_height(16);
    r.set_samples_per_pixel(1);
    r.mutable_environment()->set_data(HdrBomb(100000, 100000));
    grpc::ClientContext context;
    Prepare(&context, 60);
    auto reader = stub_->Render(&context, r);
    v1::RenderUpdate update;
    while (reader->Read(&update)) {
    }
    Expect("environment bomb", reader->Finish(), {grpc::StatusCode::INVALID_ARGUMENT});
  }

  // Twelve long calls at once from this one address, each on its own connection: at most its client's share of
  // the long-call slots is admitted, the rest refused.
  void BurstOfLongCalls() {
    std::vector<std::thread> calls;
    std::vector<grpc::Status> statuses(12);
    for (size_t i = 0; i < statuses.size(); ++i)
      calls.emplace_back([this, i, &statuses] {
        auto stub = v1::Loomlight::NewStub(OwnChannel(target_));
        v1::TabulateRequest r;  // a small in-plane table: the burst, not its size, is the attack
        r.mutable_material()->set_preset("linen_plain");
        for (double theta : {10.0, 40.0, 70.0}) r.mutable_in_plane()->add_theta_i_deg(theta);
        r.mutable_in_plane()->set_theta_o_count(90);
        grpc::ClientContext context;
        Prepare(&context, 120);
        auto reader = stub->Tabulate(&context, r);
        v1::TabulateChunk chunk;
        while (reader->Read(&chunk)) {
        }
        statuses[i] = reader->Finish();
      });
    for (auto& t : calls) t.join();
    for (const grpc::Status& s : statuses)
      Expect("burst of long calls", s, {grpc::StatusCode::OK, grpc::StatusCode::RESOURCE_EXHAUSTED});
  }

  // Forty health Watch streams held open at once (health needs no token): the extras are refused.
  void WatchFlood() {
    auto health = grpc::health::v1::Health::NewStub(channel_);
    struct Held {
      grpc::ClientContext context;
      std::unique_ptr<grpc::ClientReader<grpc::health::v1::HealthCheckResponse>> reader;
    };
    std::vector<std::unique_ptr<Held>> held;
    for (int i = 0; i < 40; ++i) {
      auto h = std::make_unique<Held>();
      Prepare(&h->context, 60);
      h->reader = health->Watch(&h->context, grpc::health::v1::HealthCheckRequest());
      grpc::health::v1::HealthCheckResponse first;
      if (h->reader->Read(&first)) {
        held.push_back(std::move(h));
        continue;
      }
      Expect("health Watch flood", h->reader->Finish(), {grpc::StatusCode::RESOURCE_EXHAUSTED});
    }
    std::this_thread::sleep_for(std::chrono::seconds(1));
    for (auto& h : held) {
      h->context.TryCancel();
      grpc::health::v1::HealthCheckResponse rest;
      while (h->reader->Read(&rest)) {
      }
      Expect("health Watch flood", h->reader->Finish(), {grpc::StatusCode::CANCELLED});
    }
  }

  struct Unread {
    grpc::ClientContext context;
    std::unique_ptr<grpc::ClientReader<v1::TabulateChunk>> reader;
    std::chrono::steady_clock::time_point started;
  };

  const std::string target_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::Loomlight::Stub> stub_;
  const std::string forwarded_for_;
  const std::function<void(const std::string&)> count_;
  std::unique_ptr<Unread> unread_;
};

}  // namespace loomlight::testing

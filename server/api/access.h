// Who may call: transport security (TLS, optionally mutual) and per-client bearer tokens from a file the
// operator manages. gRPC's auth metadata processor checks every call, reflection and all, before any handler
// runs; the client's name it finds is what fair share, per-client limits and the metrics know the client by
// (README "Security").
#pragma once

#include <grpcpp/grpcpp.h>
#include <grpcpp/security/auth_metadata_processor.h>

#include <array>
#include <cstdint>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <vector>

namespace loomlight::api {

// Proxies whose X-Forwarded-For the server believes (`--trusted-proxy`): a call from one of them is counted
// against the client address the proxy forwarded, so fair share and per-client limits still tell apart the
// clients behind a load balancer. A header from anyone else is ignored: clients cannot pick their own share.
class TrustedProxies {
 public:
  // Adds a block, "ADDRESS/BITS" or one address (IPv4 or IPv6); "" or why not.
  std::string Add(const std::string& block);
  bool empty() const { return blocks_.empty(); }
  // Whether a gRPC peer ("ipv4:10.0.0.7:41234", "ipv6:[::1]:41234") is in one of the blocks.
  bool Contains(const std::string& peer) const;

 private:
  struct Block {
    std::array<uint8_t, 16> address;  // IPv4 as IPv4-mapped IPv6
    int bits;
  };
  std::vector<Block> blocks_;
};

inline const TrustedProxies kNoTrustedProxies;

struct AccessOptions {
  std::string tls_cert, tls_key;  // PEM files; both or neither
  std::string tls_client_ca;      // PEM; set: clients must present a certificate it signed (mutual TLS)
  std::string tokens_file;        // set: every call but health needs a bearer token listed there (needs TLS)
  bool allow_plaintext_remote = false;  // plaintext on an address other than loopback
  TrustedProxies trusted_proxies;       // load balancers whose X-Forwarded-For names the client
};

// The auth context property carrying the caller's name (set by TokenTable's processor or taken from the
// client certificate's common name).
inline constexpr const char* kClientProperty = "loomlight.client";

// One token file: "TOKEN CLIENT CALLS" per line, CALLS a comma list of RPC names (Evaluate, Render, ...),
// `reflection`, `metrics`, or `*` for all; '#' starts a comment. Tokens are at least 16 characters.
class TokenTable {
 public:
  struct Entry {
    std::string token, client;
    std::set<std::string> calls;  // empty: all
    bool Allows(const std::string& call) const { return calls.empty() || calls.count(call) > 0; }
  };
  // Parses the file; nullptr with *error naming the line on failure.
  static std::shared_ptr<const TokenTable> Load(const std::string& path, std::string* error);
  // The entry holding `token` (every entry is compared, in constant time, so timing tells nothing), or null.
  const Entry* Find(const std::string& token) const;
  size_t size() const { return entries_.size(); }

 private:
  std::vector<Entry> entries_;
};

// The call an RPC path names, as token files list it: "/loomlight.v1.Loomlight/Evaluate" -> "Evaluate",
// reflection's methods -> "reflection", health's -> "health".
std::string CallName(const std::string& path);

// Checks each call's bearer token against the current table (swapped whole by Reload, so calls never see half
// a file); answers UNAUTHENTICATED without a known token, PERMISSION_DENIED for a call the token does not
// allow. Health checks need no token: load balancers and probes carry none. A connection is one client: the
// first token it authenticates with names it, and another client's token on it is PERMISSION_DENIED.
class TokenAuthProcessor : public grpc::AuthMetadataProcessor {
 public:
  explicit TokenAuthProcessor(std::shared_ptr<const TokenTable> table) : table_(std::move(table)) {}
  bool IsBlocking() const override { return false; }  // a lookup in memory
  grpc::Status Process(const InputMetadata& auth_metadata, grpc::AuthContext* context,
                       OutputMetadata* consumed_auth_metadata, OutputMetadata* response_metadata) override;
  void Replace(std::shared_ptr<const TokenTable> table);
  std::shared_ptr<const TokenTable> table() const;

 private:
  mutable std::mutex mutex_;
  std::shared_ptr<const TokenTable> table_;
};

// Whether `address` ("host:port") binds only the loopback interface.
bool IsLoopbackAddress(const std::string& address);

// The server's listening credentials for `address`, with the token processor when tokens are on (*processor
// set); "" on success, else why not (a file that cannot be read, plaintext on a remote address, tokens without
// TLS).
std::string MakeServerCredentials(const AccessOptions& options, const std::string& address,
                                  std::shared_ptr<grpc::ServerCredentials>* credentials,
                                  std::shared_ptr<TokenAuthProcessor>* processor);

// The caller's name: its token's client, else its certificate's common name, else "anonymous".
std::string ClientName(const grpc::ServerContextBase& context);

// Whom fair share and per-client limits count a call against: its client's name when the caller is known
// (token or certificate); else, for a call from a trusted proxy, the client address in the last entry of its
// X-Forwarded-For (the one the proxy appended); else its connection (peer address and port). Computed once per
// call: it looks up the auth context and the metadata.
std::string FairShareKey(const grpc::ServerContextBase& context, const TrustedProxies& proxies);

// Reads a whole file; false with *error when it cannot.
bool ReadFile(const std::string& path, std::string* text, std::string* error);

}  // namespace loomlight::api

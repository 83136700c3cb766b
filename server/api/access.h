// Who may call: transport security (TLS, optionally mutual) and per-client bearer tokens from a file the
// operator manages. gRPC's auth metadata processor checks every call, reflection and all, before any handler
// runs; the client's name it finds is what fair share, per-client limits and the metrics know the client by
// (docs/operations.md "Security: TLS, tokens, who may call what").
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

// One token file: "TOKEN CLIENT CALLS" per line, CALLS a comma list of RPC names (Evaluate, Render, ...),
// `reflection`, `metrics`, and `*` for every RPC. `*` does not include `metrics` (scraping is not an RPC): a
// scraper's token lists `metrics` itself ("*,metrics" for both). A comment starts with a '#' at the start of a
// line or after a space or tab and runs to the line's end; a '#' inside a field (a token, a client, a call) is
// an error, not the start of a comment, so a token with a '#' is never silently cut short. Tokens are at least
// 16 characters.
class TokenTable {
 public:
  struct Entry {
    std::string token, client;
    bool all_rpcs = false;        // `*`
    std::set<std::string> calls;  // listed by name
    bool Allows(const std::string& call) const {
      return (all_rpcs && call != "metrics") || calls.count(call) > 0;
    }
  };
  // Parses the file; nullptr with *error naming the line on failure.
  static std::shared_ptr<const TokenTable> Load(const std::string& path, std::string* error);
  // The entry holding `token`, or null. Every entry is compared, each in time that depends only on the length of
// the token given (not on where or whether it differs, nor on the listed token's length), so timing tells
// nothing about the tokens listed.
  const Entry* Find(const std::string& token) const;
  size_t size() const { return entries_.size(); }

 private:
  std::vector<Entry> entries_;
};

// The call an RPC path names, as token files and the metrics' labels know it: "/loomlight.v1.Loomlight/Evaluate"
// -> "Evaluate", reflection's methods -> "reflection", health's -> "health", and any path that is none of the
// service's methods -> "unknown" (one name, so a client inventing method names cannot grow the metrics).
std::string CallName(const std::string& path);

// Checks each call's bearer token against the current table (swapped whole by Replace, so calls never see half
// a file); answers UNAUTHENTICATED without a known token, PERMISSION_DENIED for a call the token does not
// allow. Health checks need no token: load balancers and probes carry none.
//
// Each call is the client its own token names, whatever else its connection carried: a proxy (HAProxy) sends
// many clients' calls over one connection. gRPC 1.51 hands the processor the connection's auth context (the
// server auth filter passes its channel's; a call's security context refers to the same one), so nothing
// per call can be stored there; the token stays in the call's metadata instead, and ClientName looks it up.
class TokenAuthProcessor : public grpc::AuthMetadataProcessor {
 public:
  explicit TokenAuthProcessor(std::shared_ptr<const TokenTable> table);
  ~TokenAuthProcessor() override;
  bool IsBlocking() const override { return false; }  // a lookup in memory
  grpc::Status Process(const InputMetadata& auth_metadata, grpc::AuthContext* context,
                       OutputMetadata* consumed_auth_metadata, OutputMetadata* response_metadata) override;
  // A new table; ends a failure.
  void Replace(std::shared_ptr<const TokenTable> table);
  // The token file failed to reload: fail closed. No token is valid (a token the operator removed must not
  // stay valid because the new file has a typo) until a reload succeeds; calls are told why, and the server
  // reports NOT_SERVING meanwhile.
  void Fail(const std::string& reason);
  std::shared_ptr<const TokenTable> table() const;
  std::string failure() const;  // "" unless the last reload failed

 private:
  mutable std::mutex mutex_;
  std::shared_ptr<const TokenTable> table_;
  std::string failure_;
};

// Whether `address` ("host:port") binds only the loopback interface: "unix:" paths; literal addresses in
// 127.0.0.0/8, ::1 and IPv4-mapped 127.0.0.0/8; a name only when it resolves, and every address it resolves
// to is one of those ("127.evil.example" is a name like any other).
bool IsLoopbackAddress(const std::string& address);

// The server's listening credentials for `address`, with the token processor when tokens are on (*processor
// set); "" on success, else why not (a file that cannot be read, plaintext on a remote address, tokens without
// TLS).
std::string MakeServerCredentials(const AccessOptions& options, const std::string& address,
                                  std::shared_ptr<grpc::ServerCredentials>* credentials,
                                  std::shared_ptr<TokenAuthProcessor>* processor);

// The caller's name: the client its own bearer token names (looked up per call in the live token tables), else
// its certificate's common name, else "anonymous".
std::string ClientName(const grpc::ServerContextBase& context);

// Whether the caller's bearer token lists `right` itself (`*` does not include it), e.g. `admin`: replacing and
// deleting other clients' BTF assets. Without a token, false.
bool TokenListsRight(const grpc::ServerContextBase& context, const std::string& right);

// Whom fair share and per-client limits count a call against: its client's name when the caller is known
// (token or certificate); else, for a call from a trusted proxy, the client address in the last entry of its
// X-Forwarded-For (the one the proxy appended); else its peer's address (not its port: a host is one client
// however many connections it opens). Addresses are spelt one way (IPv4 as IPv4-mapped IPv6). Computed once per
// call: it looks up the auth context and the metadata.
std::string FairShareKey(const grpc::ServerContextBase& context, const TrustedProxies& proxies);

// Reads a whole file; false with *error when it cannot.
bool ReadFile(const std::string& path, std::string* text, std::string* error);

}  // namespace loomlight::api

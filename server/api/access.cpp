#include "server/api/access.h"

#include <arpa/inet.h>
#include <grpcpp/security/server_credentials.h>

#include <cstring>

#include <fstream>
#include <sstream>
#include <string_view>

namespace loomlight::api {
namespace {

constexpr size_t kMinTokenChars = 16;  // shorter tokens are guessable
constexpr size_t kMaxTokenFileBytes = size_t{1} << 20;
constexpr const char* kBearer = "Bearer ";

// Compares every byte whatever the first difference, so the time taken does not tell how much matched.
bool EqualInConstantTime(const std::string& a, const std::string& b) {
  if (a.size() != b.size()) return false;
  unsigned char difference = 0;
  for (size_t i = 0; i < a.size(); ++i) difference |= static_cast<unsigned char>(a[i] ^ b[i]);
  return difference == 0;
}

// An IPv4 or IPv6 address as 16 bytes (IPv4 mapped into IPv6), or false.
bool ParseAddress(const std::string& text, std::array<uint8_t, 16>* out) {
  in_addr v4;
  if (inet_pton(AF_INET, text.c_str(), &v4) == 1) {
    out->fill(0);
    (*out)[10] = (*out)[11] = 0xff;
    std::memcpy(out->data() + 12, &v4, 4);
    return true;
  }
  in6_addr v6;
  if (inet_pton(AF_INET6, text.c_str(), &v6) == 1) {
    std::memcpy(out->data(), &v6, 16);
    return true;
  }
  return false;
}

// The host of "HOST:PORT" ("[V6]:PORT" unbracketed; the whole text when there is no port).
std::string HostOf(const std::string& address) {
  const size_t colon = address.rfind(':');
  std::string host = colon == std::string::npos ? address : address.substr(0, colon);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
  return host;
}

// The host of a gRPC peer string ("ipv4:10.0.0.7:41234", "ipv6:[::1]:41234"); "" for others (unix sockets).
std::string PeerHost(const std::string& peer) {
  if (peer.rfind("ipv4:", 0) != 0 && peer.rfind("ipv6:", 0) != 0) return "";
  std::string host = HostOf(peer.substr(5));
  // An IPv6 zone ("fe80::1%25eth0", percent-encoded) is not part of the address.
  if (const size_t zone = host.find('%'); zone != std::string::npos) host.resize(zone);
  return host;
}

std::string Trim(std::string_view text) {
  const size_t first = text.find_first_not_of(" \t");
  if (first == std::string_view::npos) return "";
  const size_t last = text.find_last_not_of(" \t");
  return std::string(text.substr(first, last - first + 1));
}

}  // namespace

std::string TrustedProxies::Add(const std::string& block) {
  const size_t slash = block.find('/');
  const std::string address = block.substr(0, slash);
  Block parsed;
  if (!ParseAddress(address, &parsed.address))
    return "--trusted-proxy: '" + block.substr(0, 64) + "' is not ADDRESS or ADDRESS/BITS (an IPv4 or IPv6 address)";
  const bool v4 = address.find(':') == std::string::npos;
  const int max_bits = v4 ? 32 : 128;
  int bits = max_bits;
  if (slash != std::string::npos) {
    const std::string text = block.substr(slash + 1);
    char* end = nullptr;
    const long n = std::strtol(text.c_str(), &end, 10);
    if (text.empty() || *end || n < 0 || n > max_bits)
      return "--trusted-proxy: '" + block.substr(0, 64) + "' needs a prefix length of 0.." +
             std::to_string(max_bits);
    bits = static_cast<int>(n);
  }
  parsed.bits = v4 ? bits + 96 : bits;  // an IPv4 block is a block of IPv4-mapped addresses
  blocks_.push_back(parsed);
  return "";
}

bool TrustedProxies::Contains(const std::string& peer) const {
  std::array<uint8_t, 16> address;
  if (blocks_.empty() || !ParseAddress(PeerHost(peer), &address)) return false;
  for (const Block& block : blocks_) {
    int bits = block.bits;
    bool match = true;
    for (int i = 0; i < 16 && bits > 0 && match; ++i, bits -= 8) {
      const uint8_t mask = bits >= 8 ? 0xff : static_cast<uint8_t>(0xff << (8 - bits));
      match = ((address[i] ^ block.address[i]) & mask) == 0;
    }
    if (match) return true;
  }
  return false;
}

bool ReadFile(const std::string& path, std::string* text, std::string* error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *error = "cannot read " + path;
    return false;
  }
  std::ostringstream buffer;
  buffer << in.rdbuf();
  *text = buffer.str();
  return true;
}

std::shared_ptr<const TokenTable> TokenTable::Load(const std::string& path, std::string* error) {
  std::string text;
  if (!ReadFile(path, &text, error)) return nullptr;
  if (text.size() > kMaxTokenFileBytes) {
    *error = path + " is larger than 1 MiB";
    return nullptr;
  }
  auto table = std::make_shared<TokenTable>();
  std::istringstream lines(text);
  std::string line;
  for (int number = 1; std::getline(lines, line); ++number) {
    if (const size_t hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    std::istringstream fields(line);
    Entry entry;
    std::string calls, extra;
    if (!(fields >> entry.token)) continue;  // blank or comment
    const std::string where = path + ":" + std::to_string(number);
    if (!(fields >> entry.client >> calls) || (fields >> extra)) {
      *error = where + ": expected 'TOKEN CLIENT CALLS'";
      return nullptr;
    }
    if (entry.token.size() < kMinTokenChars) {
      *error = where + ": the token is shorter than " + std::to_string(kMinTokenChars) + " characters";
      return nullptr;
    }
    for (const Entry& other : table->entries_)
      if (other.token == entry.token) {
        *error = where + ": the token is listed twice";
        return nullptr;
      }
    if (calls != "*") {
      std::istringstream names(calls);
      for (std::string name; std::getline(names, name, ',');)
        if (!name.empty()) entry.calls.insert(name);
      if (entry.calls.empty()) {
        *error = where + ": no calls listed (use '*' for all)";
        return nullptr;
      }
    }
    table->entries_.push_back(std::move(entry));
  }
  return table;
}

const TokenTable::Entry* TokenTable::Find(const std::string& token) const {
  const Entry* found = nullptr;
  for (const Entry& entry : entries_)
    if (EqualInConstantTime(entry.token, token)) found = &entry;
  return found;
}

std::string CallName(const std::string& path) {
  if (path.rfind("/grpc.reflection.", 0) == 0) return "reflection";
  if (path.rfind("/grpc.health.", 0) == 0) return "health";
  const size_t slash = path.rfind('/');
  return slash == std::string::npos ? path : path.substr(slash + 1);
}

grpc::Status TokenAuthProcessor::Process(const InputMetadata& auth_metadata, grpc::AuthContext* context,
                                         OutputMetadata* consumed_auth_metadata, OutputMetadata*) {
  std::string call;
  if (auto path = auth_metadata.find(":path"); path != auth_metadata.end())
    call = CallName(std::string(path->second.data(), path->second.size()));
  if (call == "health") return grpc::Status::OK;
  auto header = auth_metadata.find("authorization");
  if (header == auth_metadata.end())
    return {grpc::StatusCode::UNAUTHENTICATED, "no bearer token: send 'authorization: Bearer TOKEN'"};
  const std::string value(header->second.data(), header->second.size());
  if (value.rfind(kBearer, 0) != 0)
    return {grpc::StatusCode::UNAUTHENTICATED, "the authorization header is not 'Bearer TOKEN'"};
  const std::shared_ptr<const TokenTable> current = table();
  const TokenTable::Entry* entry = current->Find(value.substr(std::char_traits<char>::length(kBearer)));
  if (entry == nullptr) return {grpc::StatusCode::UNAUTHENTICATED, "unknown bearer token"};
  if (call.empty() || !entry->Allows(call))
    return {grpc::StatusCode::PERMISSION_DENIED,
            "client '" + entry->client + "' may not call " + (call.empty() ? "this method" : call)};
  // The context is the connection's (gRPC hands the processor the channel's auth context): it names its
  // client once, and a connection that authenticated as one client cannot call as another.
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const std::vector<grpc::string_ref> named = context->FindPropertyValues(kClientProperty);
    if (named.empty())
      context->AddProperty(kClientProperty, entry->client);
    else if (named.front() != entry->client)
      return {grpc::StatusCode::PERMISSION_DENIED,
              "this connection is client '" + std::string(named.front().data(), named.front().size()) +
                  "'; another client's token needs its own connection"};
  }
  // Handlers never see the token.
  consumed_auth_metadata->insert({"authorization", value});
  return grpc::Status::OK;
}

void TokenAuthProcessor::Replace(std::shared_ptr<const TokenTable> table) {
  std::lock_guard<std::mutex> lock(mutex_);
  table_ = std::move(table);
}

std::shared_ptr<const TokenTable> TokenAuthProcessor::table() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return table_;
}

bool IsLoopbackAddress(const std::string& address) {
  if (address.rfind("unix:", 0) == 0) return true;
  const std::string host = HostOf(address);
  return host == "localhost" || host == "::1" || host.rfind("127.", 0) == 0;
}

std::string MakeServerCredentials(const AccessOptions& options, const std::string& address,
                                  std::shared_ptr<grpc::ServerCredentials>* credentials,
                                  std::shared_ptr<TokenAuthProcessor>* processor) {
  const bool tls = !options.tls_cert.empty() || !options.tls_key.empty();
  if (!tls) {
    if (!options.tokens_file.empty())
      return "--tokens needs TLS (--tls-cert and --tls-key): bearer tokens must not travel in plaintext";
    if (!options.tls_client_ca.empty()) return "--tls-client-ca needs --tls-cert and --tls-key";
    if (!options.allow_plaintext_remote && !IsLoopbackAddress(address))
      return "refusing plaintext on " + address +
             ", which is not a loopback address: give --tls-cert and --tls-key, or --allow-plaintext-remote";
    *credentials = grpc::InsecureServerCredentials();
    return "";
  }
  if (options.tls_cert.empty() || options.tls_key.empty()) return "--tls-cert and --tls-key go together";
  grpc::SslServerCredentialsOptions ssl;
  grpc::SslServerCredentialsOptions::PemKeyCertPair pair;
  std::string error;
  if (!ReadFile(options.tls_key, &pair.private_key, &error) || !ReadFile(options.tls_cert, &pair.cert_chain, &error))
    return error;
  ssl.pem_key_cert_pairs.push_back(std::move(pair));
  if (!options.tls_client_ca.empty()) {
    if (!ReadFile(options.tls_client_ca, &ssl.pem_root_certs, &error)) return error;
    ssl.client_certificate_request = GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY;
  }
  *credentials = grpc::SslServerCredentials(ssl);
  if (!options.tokens_file.empty()) {
    auto table = TokenTable::Load(options.tokens_file, &error);
    if (!table) return error;
    *processor = std::make_shared<TokenAuthProcessor>(std::move(table));
    (*credentials)->SetAuthMetadataProcessor(*processor);
  }
  return "";
}

std::string ClientName(const grpc::ServerContextBase& context) {
  const std::shared_ptr<const grpc::AuthContext> auth = context.auth_context();
  if (auth) {
    // One value at most: the processor names a connection's client once.
    for (const grpc::string_ref& value : auth->FindPropertyValues(kClientProperty))
      return std::string(value.data(), value.size());
    for (const grpc::string_ref& value : auth->FindPropertyValues(GRPC_X509_CN_PROPERTY_NAME))
      return std::string(value.data(), value.size());
  }
  return "anonymous";
}

std::string FairShareKey(const grpc::ServerContextBase& context, const TrustedProxies& proxies) {
  std::string name = ClientName(context);
  if (name != "anonymous") return "client:" + name;
  const std::string peer = context.peer();
  if (proxies.Contains(peer)) {
    // The proxy appends its client last; whatever came before is the client's own say and not believed.
    const grpc::string_ref* last = nullptr;
    const auto range = context.client_metadata().equal_range("x-forwarded-for");
    for (auto it = range.first; it != range.second; ++it) last = &it->second;
    if (last) {
      const std::string_view value(last->data(), last->size());
      const size_t comma = value.rfind(',');
      const std::string client = Trim(comma == std::string_view::npos ? value : value.substr(comma + 1));
      std::array<uint8_t, 16> address;
      char canonical[INET6_ADDRSTRLEN];  // one key per address, however the proxy spelled it
      if (ParseAddress(client, &address) && inet_ntop(AF_INET6, address.data(), canonical, sizeof canonical))
        return std::string("forwarded:") + canonical;
    }
  }
  return "peer:" + peer;
}

}  // namespace loomlight::api

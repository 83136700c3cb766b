#include "server/api/access.h"

#include <arpa/inet.h>
#include <strings.h>
#include <grpcpp/security/server_credentials.h>
#include <netdb.h>

#include <algorithm>
#include <cstring>

#include <fstream>
#include <sstream>
#include <string_view>

#include "loomlight/v1/loomlight.pb.h"
#include "server/models/quote.h"

namespace loomlight::api {
namespace {

constexpr size_t kMinTokenChars = 16;  // shorter tokens are guessable
constexpr size_t kMaxTokenFileBytes = size_t{1} << 20;
constexpr const char* kBearer = "Bearer ";

// Compares every byte of the token given whatever the first difference, and a length mismatch too, so the
// time taken depends on the given token's length only: not on how much matched, nor on the listed token's
// length (`listed` is never empty: tokens have at least kMinTokenChars).
bool EqualInConstantTime(const std::string& listed, const std::string& given) {
  size_t difference = listed.size() ^ given.size();
  for (size_t i = 0; i < given.size(); ++i)
    difference |= static_cast<unsigned char>(listed[i % listed.size()] ^ given[i]);
  return difference == 0;
}

// Whether a 16-byte address (IPv4 mapped into IPv6) is loopback: 127.0.0.0/8 or ::1.
bool IsLoopback(const std::array<uint8_t, 16>& a) {
  static constexpr std::array<uint8_t, 12> kMapped = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0xff, 0xff};
  if (std::equal(kMapped.begin(), kMapped.end(), a.begin())) return a[12] == 127;
  return std::all_of(a.begin(), a.end() - 1, [](uint8_t b) { return b == 0; }) && a[15] == 1;
}

// An address as 16 bytes, IPv4 mapped into IPv6 (true, for the callers' convenience).
bool AddressBytes(const in_addr& v4, std::array<uint8_t, 16>* out) {
  out->fill(0);
  (*out)[10] = (*out)[11] = 0xff;
  std::memcpy(out->data() + 12, &v4, 4);
  return true;
}
bool AddressBytes(const in6_addr& v6, std::array<uint8_t, 16>* out) {
  std::memcpy(out->data(), &v6, 16);
  return true;
}

// An IPv4 or IPv6 address as 16 bytes (IPv4 mapped into IPv6), or false.
bool ParseAddress(const std::string& text, std::array<uint8_t, 16>* out) {
  in_addr v4;
  if (inet_pton(AF_INET, text.c_str(), &v4) == 1) return AddressBytes(v4, out);
  in6_addr v6;
  if (inet_pton(AF_INET6, text.c_str(), &v6) == 1) return AddressBytes(v6, out);
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

// One spelling per address, however it was written or reached (IPv4 as IPv4-mapped IPv6: "::ffff:10.0.0.7"); ""
// when `text` is not an address.
std::string CanonicalAddress(const std::string& text) {
  std::array<uint8_t, 16> address;
  char canonical[INET6_ADDRSTRLEN];
  if (!ParseAddress(text, &address) || !inet_ntop(AF_INET6, address.data(), canonical, sizeof canonical)) return "";
  return canonical;
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
    const std::string where = path + ":" + std::to_string(number);
    for (size_t i = 0; i < line.size(); ++i)
      if (line[i] == '#' && (i == 0 || line[i - 1] == ' ' || line[i - 1] == '\t')) {
        line.resize(i);  // a comment
        break;
      }
    if (line.find('#') != std::string::npos) {
      *error = where + ": '#' inside a field (a comment starts at the line's start or after a space or tab)";
      return nullptr;
    }
    std::istringstream fields(line);
    Entry entry;
    std::string calls, extra;
    if (!(fields >> entry.token)) continue;  // blank or comment
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
    std::istringstream names(calls);
    for (std::string name; std::getline(names, name, ',');)
      if (name == "*") entry.all_rpcs = true;
      else if (!name.empty()) entry.calls.insert(name);
    if (!entry.all_rpcs && entry.calls.empty()) {
      *error = where + ": no calls listed (use '*' for every RPC)";
      return nullptr;
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
  // The service's own methods, as its descriptor lists them: a name a client makes up is "unknown".
  static const google::protobuf::ServiceDescriptor* const service =
      v1::ListModelsRequest::descriptor()->file()->FindServiceByName("Loomlight");
  static const std::string prefix = "/" + service->full_name() + "/";
  if (path.rfind(prefix, 0) == 0 && service->FindMethodByName(path.substr(prefix.size())) != nullptr)
    return path.substr(prefix.size());
  return "unknown";
}

namespace {

// The live processors (one per server with tokens: a process runs one, tests several), for ClientName. Never
// destroyed: gRPC may let go of a server's credentials, and so of its processor, during the process's exit.
struct Processors {
  std::mutex mutex;
  std::vector<const TokenAuthProcessor*> live;
};
Processors& LiveProcessors() {
  static Processors* const processors = new Processors;
  return *processors;
}

// The bearer token a call carries, or "".
std::string_view BearerToken(std::string_view header) {
  const std::string_view bearer = kBearer;
  return header.substr(0, bearer.size()) == bearer ? header.substr(bearer.size()) : std::string_view();
}

// The live token table's entry for the token a call carries (its table held, so a reload cannot free the entry
// while it is read); entry null without a known token.
struct CallerToken {
  std::shared_ptr<const TokenTable> table;
  const TokenTable::Entry* entry = nullptr;
};
CallerToken FindCallerToken(const grpc::ServerContextBase& context) {
  const auto header = context.client_metadata().find("authorization");
  if (header == context.client_metadata().end()) return {};
  const std::string token(BearerToken(std::string_view(header->second.data(), header->second.size())));
  if (token.empty()) return {};
  Processors& processors = LiveProcessors();
  std::lock_guard<std::mutex> lock(processors.mutex);
  for (const TokenAuthProcessor* processor : processors.live) {
    CallerToken found{processor->table(), nullptr};
    if ((found.entry = found.table->Find(token))) return found;
  }
  return {};
}

}  // namespace

TokenAuthProcessor::TokenAuthProcessor(std::shared_ptr<const TokenTable> table) : table_(std::move(table)) {
  Processors& processors = LiveProcessors();
  std::lock_guard<std::mutex> lock(processors.mutex);
  processors.live.push_back(this);
}

TokenAuthProcessor::~TokenAuthProcessor() {
  Processors& processors = LiveProcessors();
  std::lock_guard<std::mutex> lock(processors.mutex);
  processors.live.erase(std::find(processors.live.begin(), processors.live.end(), this));
}

grpc::Status TokenAuthProcessor::Process(const InputMetadata& auth_metadata, grpc::AuthContext*, OutputMetadata*,
                                         OutputMetadata*) {
  std::string path;
  if (auto found = auth_metadata.find(":path"); found != auth_metadata.end())
    path.assign(found->second.data(), found->second.size());
  const std::string call = CallName(path);
  if (call == "health") return grpc::Status::OK;
  std::string reload_failure;
  std::shared_ptr<const TokenTable> current;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    reload_failure = failure_;
    current = table_;
  }
  if (!reload_failure.empty())
    return {grpc::StatusCode::UNAUTHENTICATED,
            "the server's token file failed to reload: every token is refused until its operator fixes it"};
  auto header = auth_metadata.find("authorization");
  if (header == auth_metadata.end())
    return {grpc::StatusCode::UNAUTHENTICATED, "no bearer token: send 'authorization: Bearer TOKEN'"};
  const std::string token(BearerToken(std::string_view(header->second.data(), header->second.size())));
  if (token.empty()) return {grpc::StatusCode::UNAUTHENTICATED, "the authorization header is not 'Bearer TOKEN'"};
  const TokenTable::Entry* entry = current->Find(token);
  if (entry == nullptr) return {grpc::StatusCode::UNAUTHENTICATED, "unknown bearer token"};
  // The refusal names the caller's own client only, and the method as the client sent it, quoted and cut short.
  if (!entry->Allows(call))
    return {grpc::StatusCode::PERMISSION_DENIED,
            "client '" + entry->client + "' may not call " + (call == "unknown" ? models::Quote(path) : call)};
  // The token is not consumed: ClientName finds each call's client by it (see the class comment).
  return grpc::Status::OK;
}

void TokenAuthProcessor::Replace(std::shared_ptr<const TokenTable> table) {
  std::lock_guard<std::mutex> lock(mutex_);
  table_ = std::move(table);
  failure_.clear();
}

void TokenAuthProcessor::Fail(const std::string& reason) {
  std::lock_guard<std::mutex> lock(mutex_);
  table_ = std::make_shared<TokenTable>();
  failure_ = reason.empty() ? "the token file failed to load" : reason;
}

std::shared_ptr<const TokenTable> TokenAuthProcessor::table() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return table_;
}

std::string TokenAuthProcessor::failure() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return failure_;
}

bool IsLoopbackAddress(const std::string& address) {
  if (address.rfind("unix:", 0) == 0) return true;
  const std::string host = HostOf(address);
  if (host.empty()) return false;  // ":PORT" is every interface
  std::array<uint8_t, 16> bytes;
  if (ParseAddress(host, &bytes)) return IsLoopback(bytes);
  // A name binds every address it resolves to (as gRPC binds it): loopback only if each of them is.
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  // "localhost" is loopback by definition (RFC 6761 section 6.3) even where nothing resolves it (a bare root
  // without /etc/hosts); then gRPC cannot bind it either.
  if (getaddrinfo(host.c_str(), nullptr, &hints, &found) != 0) return strcasecmp(host.c_str(), "localhost") == 0;
  bool loopback = found != nullptr;
  for (const addrinfo* a = found; a != nullptr && loopback; a = a->ai_next)
    loopback = (a->ai_family == AF_INET
                    ? AddressBytes(reinterpret_cast<const sockaddr_in*>(a->ai_addr)->sin_addr, &bytes)
                    : a->ai_family == AF_INET6 &&
                          AddressBytes(reinterpret_cast<const sockaddr_in6*>(a->ai_addr)->sin6_addr, &bytes)) &&
               IsLoopback(bytes);
  freeaddrinfo(found);
  return loopback;
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
  if (const CallerToken caller = FindCallerToken(context); caller.entry) return caller.entry->client;
  const std::shared_ptr<const grpc::AuthContext> auth = context.auth_context();
  if (auth)
    for (const grpc::string_ref& value : auth->FindPropertyValues(GRPC_X509_CN_PROPERTY_NAME))
      return std::string(value.data(), value.size());
  return "anonymous";
}

bool TokenListsRight(const grpc::ServerContextBase& context, const std::string& right) {
  const CallerToken caller = FindCallerToken(context);
  return caller.entry && caller.entry->calls.count(right) > 0;
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
      const std::string client =
          CanonicalAddress(Trim(comma == std::string_view::npos ? value : value.substr(comma + 1)));
      if (!client.empty()) return "forwarded:" + client;
    }
  }
  // A host is one client however many connections it opens (each has its own port): more connections must not
  // buy more slots, queue share or memory. A socket with no address (unix:) is counted as its peer string.
  const std::string host = CanonicalAddress(PeerHost(peer));
  return "peer:" + (host.empty() ? peer : host);
}

}  // namespace loomlight::api

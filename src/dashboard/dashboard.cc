#include "icars/dashboard/dashboard.h"

#include <fmt/format.h>
#include <httplib.h>
#include <openssl/crypto.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <charconv>
#include <condition_variable>
#include <filesystem>
#include <mutex>
#include <thread>

#include "assets.h"
#include "icars/planet/endpoint.h"

namespace icars::dashboard {

using nlohmann::json;
using namespace std::chrono_literals;

namespace {

void reply(httplib::Response& res, int status, const json& body) {
  res.status = status;
  res.set_content(body.dump(), "application/json");
}

void refuse(httplib::Response& res, int status, const std::string& why) { reply(res, status, {{"error", why}}); }

bool loopback(const std::string& host) {
  return host == "127.0.0.1" || host == "::1" || host == "localhost" || host.starts_with("127.");
}

// Compares without leaking where they first differ.
bool same_token(const std::string& given, const std::string& token) {
  return given.size() == token.size() && CRYPTO_memcmp(given.data(), token.data(), token.size()) == 0;
}

std::optional<std::uint64_t> number_param(const httplib::Request& req, const char* name) {
  if (!req.has_param(name)) return std::nullopt;
  const auto text = req.get_param_value(name);
  std::uint64_t v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size()) return std::nullopt;
  return v;
}

}  // namespace

struct Dashboard::Impl {
  DashboardOptions options;
  Views views;
  Controls controls;
  std::optional<RecordSource> replay;
  planet::Endpoint endpoint;
  bool tls = false;
  std::shared_ptr<spdlog::logger> log;
  EventHub hub;
  std::unique_ptr<httplib::Server> server;
  std::thread thread;
  std::atomic<bool> running{false};
  // services_changed() may be called where the services cannot be read (a container's
  // watcher): the ticker reads and sends them a moment later.
  std::atomic<bool> services_dirty{false};
  std::mutex ticker_mutex;
  std::condition_variable ticker_wake;
  std::thread ticker;
  std::uint16_t port = 0;

  Impl(DashboardOptions o, Views v, Controls c)
      : options(std::move(o)), views(std::move(v)), controls(std::move(c)), hub(options.hub) {}

  json snapshot() {
    json s = {{"mode", replay ? "replay" : views.mode}, {"controls", !options.token.empty() && !replay}};
    s["house"] = views.house ? views.house() : json(nullptr);
    s["policy"] = views.policy ? views.policy() : json(nullptr);
    s["services"] = views.services ? views.services() : json::array();
    s["time"] = views.time ? views.time() : json(nullptr);
    json records = json::array();
    if (replay) {
      s["first_index"] = 0;
      s["total"] = replay->total();
    } else {
      const auto h = hub.history();
      for (const auto& r : h.records) records.push_back(json::parse(r, nullptr, false));
      s["first_index"] = h.first_index;
      s["total"] = h.total;
    }
    s["records"] = std::move(records);
    s["dropped"] = hub.dropped();
    s["pages"] = hub.clients();
    return s;
  }

  // The request's JSON object body, or a 400 already answered.
  std::optional<json> body(const httplib::Request& req, httplib::Response& res) {
    const json j = json::parse(req.body, nullptr, false);
    if (j.is_discarded() || !j.is_object()) {
      refuse(res, 400, "the body is not a JSON object");
      return std::nullopt;
    }
    return j;
  }

  // Whether the request may use the controls; if not, the refusal is answered.
  bool authorized(const httplib::Request& req, httplib::Response& res) {
    if (replay) {
      refuse(res, 403, "a replay has no controls");
      return false;
    }
    if (options.token.empty()) {
      refuse(res, 403, "controls are off: the dashboard was started without a token");
      return false;
    }
    const auto header = req.get_header_value("Authorization");
    if (!header.starts_with("Bearer ") || !same_token(header.substr(7), options.token)) {
      refuse(res, 401, "controls need the dashboard's token: Authorization: Bearer <token> (the ?token= of the URL "
                       "the mediator printed)");
      return false;
    }
    return true;
  }

  void control(const httplib::Request& req, httplib::Response& res, const std::function<json(const json&)>& run) {
    if (!authorized(req, res)) return;
    const auto j = body(req, res);
    if (!j) return;
    try {
      reply(res, 200, run(*j));
    } catch (const ControlError& e) {
      refuse(res, e.status(), e.what());
    } catch (const json::exception& e) {
      refuse(res, 400, std::string("bad field: ") + e.what());
    }
  }

  static std::string text_field(const json& j, const char* name) {
    const auto it = j.find(name);
    if (it == j.end() || !it->is_string() || it->get<std::string>().empty()) {
      throw ControlError(400, fmt::format("'{}' is missing or not a non-empty string", name));
    }
    return it->get<std::string>();
  }

  template <class F>
  static const F& offered(const F& f, const char* what) {
    if (!f) throw ControlError(409, fmt::format("{} is not offered here", what));
    return f;
  }

  void routes() {
    auto& s = *server;
    s.set_payload_max_length(options.max_body);
    // A batch of events is written as it is gathered: Nagle's algorithm would hold it for the
    // page's delayed ACK (40 ms).
    s.set_tcp_nodelay(true);
    s.new_task_queue = [threads = options.threads] { return new httplib::ThreadPool(threads); };
    s.Get("/", [](const httplib::Request&, httplib::Response& res) {
      const auto a = find_asset("index.html");
      res.set_content(std::string(a->body), std::string(a->content_type));
    });
    // The COROS fleet page (icars-coros run --http), on the same API.
    s.Get("/fleet", [](const httplib::Request&, httplib::Response& res) {
      const auto a = find_asset("fleet.html");
      res.set_content(std::string(a->body), std::string(a->content_type));
    });
    s.Get(R"(/static/([A-Za-z0-9_.-]+))", [](const httplib::Request& req, httplib::Response& res) {
      const auto a = find_asset(req.matches[1].str());
      if (!a) return refuse(res, 404, "no such file: " + req.matches[1].str());
      res.set_header("Cache-Control", "no-cache");
      res.set_content(std::string(a->body), std::string(a->content_type));
    });
    s.Get("/api/snapshot", [this](const httplib::Request&, httplib::Response& res) { reply(res, 200, snapshot()); });
    s.Get("/api/records", [this](const httplib::Request& req, httplib::Response& res) {
      const auto from = number_param(req, "from");
      const auto count = number_param(req, "count").value_or(1000);
      if (!from || count == 0 || count > 5000) {
        return refuse(res, 400, "records need from=<index> and count=<1..5000>");
      }
      json out = {{"first_index", *from}};
      json records = json::array();
      if (replay) {
        out["total"] = replay->total();
        for (const auto& line : replay->read(*from, count)) records.push_back(json::parse(line, nullptr, false));
      } else {
        const auto h = hub.history();
        out["total"] = h.total;
        if (*from < h.first_index) {
          return refuse(res, 410, fmt::format("records before {} are no longer kept (a live page keeps the last {})",
                                              h.first_index, options.hub.history));
        }
        for (auto i = *from; i < h.total && i < *from + count; ++i) {
          records.push_back(json::parse(h.records[i - h.first_index], nullptr, false));
        }
      }
      out["records"] = std::move(records);
      reply(res, 200, out);
    });
    s.Get("/api/events", [this](const httplib::Request&, httplib::Response& res) {
      if (replay) return refuse(res, 404, "a replay has no live events: page through /api/records");
      auto client = hub.connect();
      if (!client) return refuse(res, 503, fmt::format("more than {} live pages", options.hub.max_clients));
      res.set_header("Cache-Control", "no-cache");
      res.set_chunked_content_provider(
          "text/event-stream",
          [this, client](std::size_t, httplib::DataSink& sink) {
            auto batch = client->next(10s);
            if (!batch || !running) {
              sink.done();
              return false;
            }
            if (batch->empty()) *batch = ": keep-alive\n\n";
            return sink.write(batch->data(), batch->size());
          },
          [this, client](bool) { hub.disconnect(client); });
    });
    s.Post("/api/say", [this](const httplib::Request& req, httplib::Response& res) {
      control(req, res, [this](const json& j) {
        const auto user = text_field(j, "user");
        const auto text = text_field(j, "text");
        return offered(controls.say, "saying a sentence")(user, text);
      });
    });
    s.Post("/api/policy", [this](const httplib::Request& req, httplib::Response& res) {
      control(req, res, [this](const json& j) {
        return offered(controls.run_policy, "switching the policy")(text_field(j, "name"));
      });
    });
    s.Post("/api/pause", [this](const httplib::Request& req, httplib::Response& res) {
      control(req, res, [this](const json&) { return offered(controls.pause, "pausing")(); });
    });
    s.Post("/api/resume", [this](const httplib::Request& req, httplib::Response& res) {
      control(req, res, [this](const json&) { return offered(controls.resume, "resuming")(); });
    });
    s.Post("/api/speed", [this](const httplib::Request& req, httplib::Response& res) {
      control(req, res, [this](const json& j) {
        const auto it = j.find("speed");
        if (it == j.end() || !it->is_number() || !(it->get<double>() > 0)) {
          throw ControlError(400, "'speed' is missing or not a positive number");
        }
        return offered(controls.speed, "changing the speed")(it->get<double>());
      });
    });
    // Whatever no route answered, and errors without a body of their own (413 from httplib).
    s.set_error_handler([this](const httplib::Request& req, httplib::Response& res) {
      if (!res.body.empty()) return;
      switch (res.status) {
        case 404:
          return refuse(res, 404, fmt::format("no {} {} here: the page is /, its API /api/...", req.method, req.path));
        case 413:
          return refuse(res, 413, fmt::format("the request body is larger than {} bytes", options.max_body));
        case 405:
          return refuse(res, 405, fmt::format("{} is not allowed on {}", req.method, req.path));
        default:
          return refuse(res, res.status, fmt::format("request refused ({})", res.status));
      }
    });
    s.set_exception_handler([this](const httplib::Request& req, httplib::Response& res, std::exception_ptr e) {
      std::string what = "unknown error";
      try {
        std::rethrow_exception(e);
      } catch (const std::exception& ex) {
        what = ex.what();
      } catch (...) {
      }
      log->warn("{} {}: {}", req.method, req.path, what);
      refuse(res, 500, what);
    });
  }
};

Dashboard::Dashboard(DashboardOptions options, Views views, Controls controls)
    : impl_(std::make_unique<Impl>(std::move(options), std::move(views), std::move(controls))) {
  auto& m = *impl_;
  m.log = m.options.logger ? m.options.logger
                           : std::make_shared<spdlog::logger>("dashboard",
                                                              std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
  m.endpoint = planet::parse_endpoint(m.options.listen, /*allow_any_port=*/true);
  m.tls = !m.options.tls_cert.empty() || !m.options.tls_key.empty();
  if (m.tls && (m.options.tls_cert.empty() || m.options.tls_key.empty())) {
    throw std::invalid_argument("the dashboard's TLS needs both a certificate and its key");
  }
  if (!m.tls && !loopback(m.endpoint.host)) {
    throw std::invalid_argument(fmt::format(
        "the dashboard on {} would be reachable from other machines: give it a TLS certificate and key, or listen "
        "on 127.0.0.1 and reach it through an SSH tunnel",
        m.options.listen));
  }
  if (m.tls) {
    for (const auto& f : {m.options.tls_cert, m.options.tls_key}) {
      if (!std::filesystem::is_regular_file(f)) throw std::runtime_error("the dashboard cannot read " + f);
    }
    m.server = std::make_unique<httplib::SSLServer>(m.options.tls_cert.c_str(), m.options.tls_key.c_str());
    if (!m.server->is_valid()) {
      throw std::runtime_error(fmt::format("the dashboard cannot use the certificate {} with the key {}",
                                           m.options.tls_cert, m.options.tls_key));
    }
  } else {
    m.server = std::make_unique<httplib::Server>();
  }
  m.routes();
}

Dashboard::~Dashboard() { stop(); }

void Dashboard::replay(RecordSource source) { impl_->replay = std::move(source); }

std::uint16_t Dashboard::start() {
  auto& m = *impl_;
  if (m.running) return m.port;
  const int port = m.endpoint.port == 0 ? m.server->bind_to_any_port(m.endpoint.host)
                                        : (m.server->bind_to_port(m.endpoint.host, m.endpoint.port) ? m.endpoint.port : -1);
  if (port <= 0) throw std::runtime_error(fmt::format("the dashboard cannot listen on {}", m.options.listen));
  m.port = static_cast<std::uint16_t>(port);
  m.running = true;
  m.thread = std::thread([&m] { m.server->listen_after_bind(); });
  m.ticker = std::thread([&m] {
    std::unique_lock lock(m.ticker_mutex);
    while (m.running) {
      m.ticker_wake.wait_for(lock, 200ms);
      if (m.services_dirty.exchange(false) && m.views.services) {
        lock.unlock();
        m.hub.broadcast({"services", m.views.services().dump()});
        lock.lock();
      }
    }
  });
  return m.port;
}

void Dashboard::stop() {
  auto& m = *impl_;
  if (!m.running.exchange(false)) return;
  {
    std::lock_guard lock(m.ticker_mutex);
    m.ticker_wake.notify_all();
  }
  if (m.ticker.joinable()) m.ticker.join();
  m.hub.close_all();
  m.server->stop();
  if (m.thread.joinable()) m.thread.join();
}

void Dashboard::record(const behavior::TraceRecord& r) { impl_->hub.publish_record(r.to_json()); }

void Dashboard::services_changed() { impl_->services_dirty = true; }

std::string Dashboard::url() const {
  const auto& m = *impl_;
  const auto host = m.endpoint.host.find(':') != std::string::npos ? "[" + m.endpoint.host + "]" : m.endpoint.host;
  auto u = fmt::format("{}://{}:{}/", m.tls ? "https" : "http", host, m.port);
  if (!m.options.token.empty() && !m.replay) u += "?token=" + m.options.token;
  return u;
}

EventHub& Dashboard::hub() { return impl_->hub; }

}  // namespace icars::dashboard

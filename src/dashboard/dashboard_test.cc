// The dashboard's HTTP side as a browser and a script use it, over real sockets: the page and
// its files, the snapshot, the live stream, paging through records, the controls behind the
// token, and a clear 4xx for every request it cannot serve.
#include "icars/dashboard/dashboard.h"

#include <gtest/gtest.h>
#include <httplib.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>

#include "icars/dashboard/views.h"
#include "tls_files.h"

namespace icars::dashboard {
namespace {

using nlohmann::json;
using namespace std::chrono_literals;

behavior::TraceRecord note(int t, const std::string& text) {
  behavior::TraceRecord r;
  r.time = Time{t};
  r.kind = "note";
  r.source = "test";
  r.text = text;
  return r;
}

class DashboardHttp : public ::testing::Test {
 protected:
  void SetUp() override {
    Views views;
    views.house = [] { return json{{"name", "test_house"}}; };
    views.policy = [] { return json{{"name", "test_policy"}}; };
    views.services = [] { return json::array({{{"id", "tv.tv_control"}, {"available", true}}}); };
    Controls controls;
    controls.say = [this](const std::string& user, const std::string& text) {
      std::lock_guard lock(mutex_);
      said_.push_back(user + ": " + text);
      return json{{"said", text}};
    };
    controls.run_policy = [](const std::string& name) -> json {
      if (name == "broken") throw ControlError(422, "broken.xml:4: error: unknown behavior type 'Wiat'");
      return {{"policy", name}};
    };
    DashboardOptions options;
    options.token = "secret-token";
    options.hub = {.queue = 64, .history = 5, .max_clients = 8};
    options.max_body = 1024;
    dashboard_ = std::make_unique<Dashboard>(options, views, controls);
    port_ = dashboard_->start();
    client_ = std::make_unique<httplib::Client>("127.0.0.1", port_);
    client_->set_read_timeout(10, 0);
  }
  void TearDown() override { dashboard_->stop(); }

  httplib::Result post(const std::string& path, const std::string& body, const std::string& token = "secret-token") {
    httplib::Headers headers;
    if (!token.empty()) headers.emplace("Authorization", "Bearer " + token);
    return client_->Post(path.c_str(), headers, body, "application/json");
  }
  static std::string error_of(const httplib::Result& r) {
    const auto j = json::parse(r->body, nullptr, false);
    return j.is_object() ? j.value("error", "") : "(not JSON: " + r->body + ")";
  }

  std::unique_ptr<Dashboard> dashboard_;
  std::uint16_t port_ = 0;
  std::unique_ptr<httplib::Client> client_;
  std::mutex mutex_;
  std::vector<std::string> said_;
};

TEST_F(DashboardHttp, ServesThePageItsFilesAndASnapshot) {
  const auto page = client_->Get("/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  EXPECT_NE(page->body.find("<html"), std::string::npos);
  EXPECT_EQ(page->get_header_value("Content-Type"), "text/html; charset=utf-8");
  for (const auto* file : {"/static/app.js", "/static/model.js", "/static/style.css"}) {
    const auto r = client_->Get(file);
    ASSERT_TRUE(r) << file;
    EXPECT_EQ(r->status, 200) << file;
    EXPECT_FALSE(r->body.empty()) << file;
  }
  for (int i = 0; i < 7; ++i) dashboard_->record(note(1000 + i, "n" + std::to_string(i)));
  const auto snap = client_->Get("/api/snapshot");
  ASSERT_TRUE(snap);
  ASSERT_EQ(snap->status, 200);
  const auto j = json::parse(snap->body);
  EXPECT_EQ(j["mode"], "live");
  EXPECT_EQ(j["controls"], true);
  EXPECT_EQ(j["house"]["name"], "test_house");
  EXPECT_EQ(j["policy"]["name"], "test_policy");
  EXPECT_EQ(j["services"][0]["id"], "tv.tv_control");
  EXPECT_EQ(j["total"], 7);
  EXPECT_EQ(j["first_index"], 2);
  ASSERT_EQ(j["records"].size(), 5u);
  EXPECT_EQ(j["records"][0]["index"], 2);
  EXPECT_EQ(j["records"][0]["text"], "n2");
  // Paging through what is kept; what is no longer kept is a 410 that says so.
  const auto page2 = client_->Get("/api/records?from=5&count=10");
  ASSERT_TRUE(page2);
  ASSERT_EQ(page2->status, 200);
  EXPECT_EQ(json::parse(page2->body)["records"].size(), 2u);
  const auto gone = client_->Get("/api/records?from=0&count=10");
  ASSERT_TRUE(gone);
  EXPECT_EQ(gone->status, 410);
  EXPECT_NE(error_of(gone).find("no longer kept"), std::string::npos);
}

TEST_F(DashboardHttp, StreamsEveryRecordLiveToEachPage) {
  std::mutex mutex;
  std::string received;
  std::atomic<bool> enough{false};
  std::thread page([&] {
    httplib::Client c("127.0.0.1", port_);
    c.set_read_timeout(20, 0);
    c.Get("/api/events", [&](const char* data, std::size_t n) {
      std::lock_guard lock(mutex);
      received.append(data, n);
      return !enough.load();
    });
  });
  // The page is connected once the hub counts it.
  for (int i = 0; i < 500 && dashboard_->hub().clients() == 0; ++i) std::this_thread::sleep_for(10ms);
  ASSERT_EQ(dashboard_->hub().clients(), 1u);
  for (int i = 0; i < 3; ++i) dashboard_->record(note(2000 + i, "live" + std::to_string(i)));
  dashboard_->services_changed();
  for (int i = 0; i < 1000; ++i) {
    {
      std::lock_guard lock(mutex);
      if (received.find("live2") != std::string::npos && received.find("event: services") != std::string::npos) break;
    }
    std::this_thread::sleep_for(10ms);
  }
  enough = true;
  dashboard_->record(note(3000, "wake"));  // the stream notices the page left at its next write
  page.join();
  std::lock_guard lock(mutex);
  EXPECT_NE(received.find("event: record\ndata: {\"index\":0,"), std::string::npos) << received;
  EXPECT_NE(received.find("\"text\":\"live2\""), std::string::npos) << received;
  EXPECT_NE(received.find("event: services\ndata: [{"), std::string::npos) << received;
}

TEST_F(DashboardHttp, ControlsNeedTheTokenAndSayWhatWentWrong) {
  auto r = post("/api/say", R"({"user":"user1","text":"turn on the TV"})", "");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 401);
  EXPECT_NE(error_of(r).find("token"), std::string::npos);
  r = post("/api/say", R"({"user":"user1","text":"turn on the TV"})", "wrong-token!");
  EXPECT_EQ(r->status, 401);
  {
    std::lock_guard lock(mutex_);
    EXPECT_TRUE(said_.empty()) << "a control ran without the token";
  }
  r = post("/api/say", R"({"user":"user1","text":"turn on the TV"})");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200) << r->body;
  {
    std::lock_guard lock(mutex_);
    ASSERT_EQ(said_.size(), 1u);
    EXPECT_EQ(said_[0], "user1: turn on the TV");
  }
  // Malformed JSON, a missing field, a wrong type: 400 naming it.
  r = post("/api/say", R"({"user":"user1",)");
  EXPECT_EQ(r->status, 400);
  EXPECT_NE(error_of(r).find("not a JSON object"), std::string::npos);
  r = post("/api/say", R"({"user":"user1"})");
  EXPECT_EQ(r->status, 400);
  EXPECT_NE(error_of(r).find("'text'"), std::string::npos);
  r = post("/api/speed", R"({"speed":"fast"})");
  EXPECT_EQ(r->status, 400);
  // A policy that does not load: its file:line errors, with the control's status.
  r = post("/api/policy", R"({"name":"broken"})");
  EXPECT_EQ(r->status, 422);
  EXPECT_EQ(error_of(r), "broken.xml:4: error: unknown behavior type 'Wiat'");
  r = post("/api/policy", R"({"name":"paper_home"})");
  EXPECT_EQ(r->status, 200);
  // A control this dashboard does not offer.
  r = post("/api/pause", "{}");
  EXPECT_EQ(r->status, 409);
  EXPECT_NE(error_of(r).find("not offered"), std::string::npos);
}

TEST_F(DashboardHttp, BadRequestsGetA4xxWithAReason) {
  auto r = client_->Get("/no/such/page");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 404);
  EXPECT_NE(error_of(r).find("/no/such/page"), std::string::npos);
  r = client_->Get("/static/missing.js");
  EXPECT_EQ(r->status, 404);
  r = client_->Get("/static/../../etc/passwd");
  EXPECT_EQ(r->status, 404);
  r = post("/api/say", std::string(4096, 'x'));
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 413);
  EXPECT_NE(error_of(r).find("larger than 1024 bytes"), std::string::npos);
  r = client_->Get("/api/records?from=x&count=10");
  EXPECT_EQ(r->status, 400);
  r = client_->Get("/api/records?from=0&count=100000");
  EXPECT_EQ(r->status, 400);
  // And the dashboard still serves.
  r = client_->Get("/api/snapshot");
  EXPECT_EQ(r->status, 200);
}

TEST(Dashboard, ListensBeyondLoopbackOnlyWithTls) {
  EXPECT_THROW(Dashboard({.listen = "0.0.0.0:0"}, {}), std::invalid_argument);
  EXPECT_THROW(Dashboard({.listen = "not an address"}, {}), std::invalid_argument);
  const auto dir = std::filesystem::temp_directory_path() / ("icars-dashboard-tls-" + std::to_string(::getpid()));
  planet_test::make_certificates(dir);
  DashboardOptions options;
  options.listen = "0.0.0.0:0";
  options.tls_cert = (dir / "server.pem").string();
  options.tls_key = (dir / "server.key").string();
  Dashboard dashboard(options, {});
  const auto port = dashboard.start();
  EXPECT_TRUE(dashboard.url().starts_with("https://")) << dashboard.url();
  httplib::SSLClient client("127.0.0.1", port);
  client.set_ca_cert_path((dir / "ca.pem").string().c_str());
  client.enable_server_certificate_verification(true);
  const auto r = client.Get("/api/snapshot");
  ASSERT_TRUE(r) << httplib::to_string(r.error());
  EXPECT_EQ(r->status, 200);
  dashboard.stop();
  options.tls_key = (dir / "missing.key").string();
  EXPECT_THROW(Dashboard(options, {}), std::runtime_error);
  std::filesystem::remove_all(dir);
}

TEST(Dashboard, ReplaysARecordedRunPageByPage) {
  std::vector<std::string> lines;
  for (int i = 0; i < 30; ++i) lines.push_back("{\"t\":" + std::to_string(i) + ",\"kind\":\"note\"}");
  Dashboard dashboard({.token = "t"}, {});
  dashboard.replay({[&] { return static_cast<std::uint64_t>(lines.size()); },
                    [&](std::uint64_t from, std::size_t count) {
                      std::vector<std::string> out;
                      for (auto i = from; i < lines.size() && out.size() < count; ++i) out.push_back(lines[i]);
                      return out;
                    }});
  const auto port = dashboard.start();
  httplib::Client c("127.0.0.1", port);
  const auto snap = json::parse(c.Get("/api/snapshot")->body);
  EXPECT_EQ(snap["mode"], "replay");
  EXPECT_EQ(snap["controls"], false);
  EXPECT_EQ(snap["total"], 30);
  const auto page = json::parse(c.Get("/api/records?from=25&count=10")->body);
  ASSERT_EQ(page["records"].size(), 5u);
  EXPECT_EQ(page["records"][0]["t"], 25);
  EXPECT_EQ(c.Get("/api/events")->status, 404);
  httplib::Headers auth{{"Authorization", "Bearer t"}};
  EXPECT_EQ(c.Post("/api/say", auth, R"({"user":"u","text":"x"})", "application/json")->status, 403);
}

}  // namespace
}  // namespace icars::dashboard

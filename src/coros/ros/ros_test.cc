// The ROS interaction layer against a real ROS master: topic managers, an agent's knowledge
// topics, and a courier delivery driven by a ROS robot base (coros_ros_fake_base).
//
// Each test process starts its own `rosmaster --core` on a free port, with ROS_HOME and
// ROS_LOG_DIR in a fresh temporary directory, points ROS_MASTER_URI at it and kills it at the
// end; the fake base inherits that environment.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <std_msgs/Int32.h>
#include <std_msgs/String.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include "child_process.h"
#include "icars/coros/agent.h"
#include "icars/coros/courier.h"
#include "icars/coros/discovery.h"
#include "icars/coros/ros/ros_layer.h"
#include "icars/coros/ros/ros_robot.h"
#include "icars_coros_msgs/NeighborhoodList.h"
#include "icars_coros_msgs/TaskStateList.h"

namespace {

using namespace std::chrono_literals;
using icars::coros::Agent;
using icars::coros::AgentConfiguration;
using icars::coros::CorosError;
using icars::coros::ros_layer::KnowledgePublisher;
using icars::coros::ros_layer::Node;
using icars::coros::ros_layer::PublishersManager;
using icars::coros::ros_layer::SubscribersManager;
using planet_test::wait_until;

// A port that was free a moment ago (bound to port 0, then released).
std::uint16_t free_port(int type) {
  const int fd = ::socket(AF_INET, type, 0);
  if (fd < 0) throw std::runtime_error("socket failed");
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t length = sizeof address;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0 ||
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length) != 0) {
    ::close(fd);
    throw std::runtime_error("cannot find a free port");
  }
  ::close(fd);
  return ntohs(address.sin_port);
}

// argv run so that it is killed when this process dies, even by a crash or a sanitizer abort
// that skips every destructor (util-linux setpriv sets the parent-death signal, then execs).
std::vector<std::string> killed_with_us(std::vector<std::string> argv) {
  const std::string setpriv = COROS_SETPRIV;
  if (!setpriv.empty()) argv.insert(argv.begin(), {setpriv, "--pdeathsig", "KILL", "--"});
  return argv;
}

// The ROS master of this test process; ros_layer::init() has run once SetUp() returns.
class RosMaster : public ::testing::Environment {
 public:
  void SetUp() override {
    char pattern[] = "/tmp/coros_ros_test.XXXXXX";
    ASSERT_NE(::mkdtemp(pattern), nullptr);
    home_ = pattern;
    const std::string port = std::to_string(free_port(SOCK_STREAM));
    ::setenv("ROS_HOME", home_.c_str(), 1);
    ::setenv("ROS_LOG_DIR", (home_ / "log").c_str(), 1);
    ::setenv("ROS_MASTER_URI", ("http://127.0.0.1:" + port).c_str(), 1);
    ::setenv("ROS_IP", "127.0.0.1", 1);  // nodes tell each other loopback addresses
    ::unsetenv("ROS_HOSTNAME");
    master_ = std::make_unique<planet_test::ChildProcess>(
        killed_with_us({COROS_ROSMASTER, "--core", "-p", port}));
    try {
      icars::coros::ros_layer::init("coros_ros_test", {}, 60s);
    } catch (const CorosError& e) {
      FAIL() << e.what();
    }
  }
  void TearDown() override {
    master_.reset();  // SIGKILL: rosmaster --core is one process, with no children
    std::error_code ignored;
    std::filesystem::remove_all(home_, ignored);
  }

 private:
  std::filesystem::path home_;
  std::unique_ptr<planet_test::ChildProcess> master_;
};

[[maybe_unused]] ::testing::Environment* const kMaster =
    ::testing::AddGlobalTestEnvironment(new RosMaster);

// An agent with its knowledge publisher, stopped before the publisher goes (the publisher
// reads the agent's tables on the agent's thread).
struct PublishingAgent {
  explicit PublishingAgent(AgentConfiguration config)
      : agent(std::make_unique<Agent>(std::move(config))) {}
  ~PublishingAgent() {
    agent->stop();
    knowledge.reset();
  }
  void start() {
    knowledge = std::make_unique<KnowledgePublisher>(*agent);
    agent->start();
  }
  std::unique_ptr<Agent> agent;
  std::unique_ptr<KnowledgePublisher> knowledge;
};

AgentConfiguration agent_config(const std::string& id, const std::string& role,
                                std::uint16_t broadcast_port) {
  static const auto key = icars::coros::FleetKey::generate();  // one fleet per test process
  AgentConfiguration config;
  config.id = id;
  config.role = role;
  config.transport.broadcast_port = broadcast_port;
  config.transport.key = key;
  config.hello_period = 100ms;
  config.neighbor_expiry = 3000ms;  // generous: ASan builds on a loaded 2-core machine
  config.bid_window = 1500ms;       // an upper bound; auctions close when all have bid
  return config;
}

// The latest message of each topic subscribed to, and every value seen, under a lock.
template <class Msg>
class Latest {
 public:
  std::optional<Msg> get() const {
    std::lock_guard lock(mutex_);
    return latest_;
  }
  std::function<void(const Msg&)> callback() {
    return [this](const Msg& m) {
      std::lock_guard lock(mutex_);
      latest_ = m;
      all_.push_back(m);
    };
  }
  std::vector<Msg> all() const {
    std::lock_guard lock(mutex_);
    return all_;
  }

 private:
  mutable std::mutex mutex_;
  std::optional<Msg> latest_;
  std::vector<Msg> all_;
};

bool lists(const std::optional<icars_coros_msgs::NeighborhoodList>& list, const std::string& id) {
  if (!list) return false;
  for (const auto& n : list->neighbors) {
    if (n.id == id) return true;
  }
  return false;
}

TEST(RosLayer, PublishersAndSubscribersManagersRoundTrip) {
  Latest<std_msgs::String> received, late;  // outlive the subscribers that fill them
  Node node("/round_trip");
  PublishersManager publishers(node);
  SubscribersManager subscribers(node);

  subscribers.add<std_msgs::String>("chatter", "chatter", received.callback());
  publishers.add<std_msgs::String>("chatter", "chatter");
  EXPECT_TRUE(publishers.has("chatter"));
  EXPECT_FALSE(publishers.has("other"));
  EXPECT_TRUE(subscribers.has("chatter"));
  EXPECT_EQ(publishers.topic("chatter"), "/round_trip/chatter");
  EXPECT_EQ(subscribers.topic("chatter"), "/round_trip/chatter");
  ASSERT_TRUE(wait_until(
      [&] {
        return publishers.subscriber_count("chatter") > 0 &&
               subscribers.publisher_count("chatter") > 0;
      },
      30s));

  std_msgs::String hello;
  hello.data = "hello";
  publishers.publish("chatter", hello);
  ASSERT_TRUE(wait_until(
      [&] {
        const auto last = received.get();
        return last && last->data == "hello";
      },
      30s));

  // Misuse is reported, naming the key.
  EXPECT_THROW(publishers.publish("unknown", hello), CorosError);
  EXPECT_THROW(publishers.publish("chatter", std_msgs::Int32{}), CorosError);
  EXPECT_THROW(publishers.add<std_msgs::String>("chatter", "elsewhere"), CorosError);
  EXPECT_THROW(subscribers.add<std_msgs::String>("chatter", "elsewhere", [](const auto&) {}),
               CorosError);
  EXPECT_THROW(publishers.add<std_msgs::String>("bad", "no spaces allowed"), CorosError);

  // A removed subscriber hears nothing more; a latched publisher serves a late subscriber.
  EXPECT_TRUE(subscribers.remove("chatter"));
  EXPECT_FALSE(subscribers.remove("chatter"));
  EXPECT_FALSE(subscribers.has("chatter"));
  publishers.add<std_msgs::String>("latched", "latched", 1, true);
  std_msgs::String kept;
  kept.data = "kept";
  publishers.publish("latched", kept);
  subscribers.add<std_msgs::String>("late", "latched", late.callback());
  ASSERT_TRUE(wait_until(
      [&] {
        const auto last = late.get();
        return last && last->data == "kept";
      },
      30s));
  EXPECT_EQ(received.all().size(), 1u);
}

TEST(RosLayer, NamesAreCheckedAndMadeValid) {
  EXPECT_THROW(Node("not a namespace"), CorosError);
  EXPECT_EQ(icars::coros::ros_layer::ros_name("robot-1.a"), "robot_1_a");
  EXPECT_EQ(icars::coros::ros_layer::ros_name("1st"), "n1st");
}

TEST(RosLayer, KnowledgePublisherShowsNeighborhoods) {
  const std::uint16_t port = free_port(SOCK_DGRAM);
  PublishingAgent alpha(agent_config("alpha", "robot", port));
  PublishingAgent beta(agent_config("beta", "user", port));
  alpha.agent->add_operator(std::make_shared<icars::coros::DiscoveryOperator>());
  beta.agent->add_operator(std::make_shared<icars::coros::DiscoveryOperator>());

  Latest<icars_coros_msgs::NeighborhoodList> of_alpha, of_beta;
  Node node;
  SubscribersManager subscribers(node);
  subscribers.add<icars_coros_msgs::NeighborhoodList>(
      "alpha", KnowledgePublisher::neighborhood_topic("alpha"), of_alpha.callback());
  subscribers.add<icars_coros_msgs::NeighborhoodList>(
      "beta", KnowledgePublisher::neighborhood_topic("beta"), of_beta.callback());
  EXPECT_EQ(subscribers.topic("alpha"), "/alpha/neighborhood_list");

  alpha.start();
  beta.start();
  ASSERT_TRUE(wait_until([&] { return lists(of_alpha.get(), "beta"); }, 30s))
      << "alpha's neighbourhood never listed beta";
  ASSERT_TRUE(wait_until([&] { return lists(of_beta.get(), "alpha"); }, 30s))
      << "beta's neighbourhood never listed alpha";
  const auto list = *of_alpha.get();
  EXPECT_EQ(list.agent, "alpha");
  EXPECT_GT(list.stamp, 0);
  ASSERT_EQ(list.neighbors.size(), 1u);
  EXPECT_EQ(list.neighbors[0].role, "user");
  EXPECT_GT(list.neighbors[0].port, 0);

  // Beta goes quiet: alpha's list drops it once its HELLOs are older than the expiry.
  beta.agent->stop();
  ASSERT_TRUE(wait_until(
      [&] {
        const auto now = of_alpha.get();
        return now && !lists(now, "beta");
      },
      30s))
      << "beta stayed in alpha's neighbourhood after it stopped";
}

TEST(RosCourier, DeliveryDrivenByARosBase) {
  using icars::coros::CourierRobotOperator;
  using icars::coros::CourierUserOperator;
  using icars::coros::DiscoveryOperator;
  const auto map = icars::coros::MapPlanner::load(ICARS_HOUSES_DIR "/office_floor.xml", 0.25);
  const std::string pickup = "office_101", dropoff = "office_102";
  const icars::sim::Point start = map->locate("dock1");
  const icars::sim::Point dropoff_point = map->locate(dropoff);
  // Declared before the agents, which write to it until they stop.
  std::mutex events_mutex;
  std::string events;  // every agent event, shown when something fails
  auto sink = [&](const nlohmann::json& e) {
    std::lock_guard lock(events_mutex);
    events += e.dump() + "\n";
  };
  auto all_events = [&] {
    std::lock_guard lock(events_mutex);
    return events;
  };

  planet_test::ChildProcess base(
      killed_with_us({COROS_ROS_FAKE_BASE, "--ns", "rosbot", "--x", std::to_string(start.x), "--y",
                      std::to_string(start.y), "--speed", "2.0"}));
  std::optional<std::string> line;
  while ((line = base.read_line(60s)) && *line != "ready") {
  }
  ASSERT_EQ(line, "ready") << "the fake base did not start";

  const std::uint16_t port = free_port(SOCK_DGRAM);
  auto robot_config = agent_config("rosbot", "robot", port);
  auto robot = icars::coros::make_ros_robot(robot_config, map);
  ASSERT_TRUE(
      wait_until([&] { return icars::sim::distance(robot->pose().position(), start) < 0.01; }, 30s))
      << "no odometry from the fake base";

  Latest<icars_coros_msgs::TaskStateList> tasks;
  Node node;
  SubscribersManager subscribers(node);
  subscribers.add<icars_coros_msgs::TaskStateList>(
      "tasks", KnowledgePublisher::task_states_topic("rosbot"), tasks.callback(), 100);

  PublishingAgent robot_agent(robot_config);
  robot_agent.agent->add_operator(std::make_shared<DiscoveryOperator>());
  robot_agent.agent->add_operator(std::make_shared<CourierRobotOperator>(robot, map));
  auto user_config = agent_config("user", "user", port);
  PublishingAgent user_agent(user_config);
  auto courier = std::make_shared<CourierUserOperator>(map);
  user_agent.agent->add_operator(std::make_shared<DiscoveryOperator>());
  user_agent.agent->add_operator(courier);
  robot_agent.agent->set_event_sink(sink);
  user_agent.agent->set_event_sink(sink);
  robot_agent.start();
  user_agent.start();
  Agent& user = *user_agent.agent;

  ASSERT_TRUE(wait_until(
      [&] { return user.call([&] { return user.neighbors().find("rosbot") != nullptr; }); }, 30s))
      << "the user never saw the robot";
  const std::string task = user.call([&] { return courier->request(pickup, dropoff); });

  ASSERT_TRUE(wait_until(
      [&] { return user.call([&] { return courier->deliveries().at(task).finished; }); }, 120s))
      << "the delivery did not finish\n"
      << all_events();
  const auto record = user.call([&] { return courier->deliveries().at(task); });
  EXPECT_TRUE(record.success) << record.detail << "\n" << all_events();
  EXPECT_EQ(record.robot, "rosbot");

  // The robot's task topic showed the task delivered.
  EXPECT_TRUE(wait_until(
      [&] {
        for (const auto& list : tasks.all()) {
          for (const auto& t : list.tasks) {
            if (t.id == task && t.stage == "delivered") return true;
          }
        }
        return false;
      },
      30s))
      << "/rosbot/task_states never showed " << task << " delivered";
  std::set<std::string> stages;
  for (const auto& list : tasks.all()) {
    for (const auto& t : list.tasks) {
      if (t.id == task) stages.insert(t.stage);
    }
  }
  EXPECT_TRUE(stages.contains("to_pickup") || stages.contains("picked_up") ||
              stages.contains("to_dropoff"))
      << "no stage between assignment and delivery was published";

  // The fake base drove the robot to the dropoff.
  EXPECT_LT(icars::sim::distance(robot->pose().position(), dropoff_point), 0.3);
  EXPECT_GT(robot->odometer(), icars::sim::distance(start, dropoff_point));
}

}  // namespace

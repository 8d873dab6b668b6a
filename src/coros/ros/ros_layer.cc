#include "icars/coros/ros/ros_layer.h"

#include <fmt/format.h>

#include <ros/callback_queue_interface.h>
#include <ros/init.h>
#include <ros/master.h>
#include <ros/names.h>
#include <ros/this_node.h>

#include <boost/make_shared.hpp>
#include <optional>
#include <thread>

#include "icars/coros/agent.h"
#include "icars/coros/knowledge.h"
#include "icars_coros_msgs/NeighborhoodList.h"
#include "icars_coros_msgs/TaskStateList.h"

namespace icars::coros::ros_layer {

namespace {

// roscpp keeps one node per process; this only serializes concurrent init() calls.
std::mutex& init_mutex() {
  static std::mutex mutex;
  return mutex;
}

class FunctionCallback : public ros::CallbackInterface {
 public:
  explicit FunctionCallback(std::function<void()> fn) : fn_(std::move(fn)) {}
  CallResult call() override {
    fn_();
    return Success;
  }

 private:
  std::function<void()> fn_;
};

std::string checked_namespace(const std::string& ns) {
  if (!ros::isStarted()) {
    throw CorosError("ros_layer::Node '" + ns + "': call ros_layer::init() first");
  }
  std::string error;
  if (!ns.empty() && !ros::names::validate(ns, error)) {
    throw CorosError("ros_layer::Node: namespace '" + ns + "' is not a ROS name: " + error);
  }
  return ns;
}

}  // namespace

std::string ros_name(std::string_view text) {
  std::string name;
  for (const char c : text) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9');
    name += ok ? c : '_';
  }
  if (name.empty() || !((name[0] >= 'a' && name[0] <= 'z') || (name[0] >= 'A' && name[0] <= 'Z'))) {
    name.insert(0, "n");
  }
  return name;
}

void init(const std::string& node_name, const std::map<std::string, std::string>& remappings,
          std::chrono::milliseconds master_wait) {
  std::lock_guard lock(init_mutex());
  if (!ros::isInitialized()) {
    try {
      ros::init(ros::M_string(remappings.begin(), remappings.end()), ros_name(node_name),
                ros::init_options::NoSigintHandler | ros::init_options::AnonymousName);
    } catch (const ros::Exception& e) {
      throw CorosError("ros_layer::init('" + node_name + "'): " + e.what());
    }
  }
  const auto deadline = std::chrono::steady_clock::now() + master_wait;
  while (!ros::master::check()) {
    if (std::chrono::steady_clock::now() >= deadline) {
      throw CorosError("ROS master at " + ros::master::getURI() + " did not answer within " +
                       std::to_string(master_wait.count()) +
                       " ms: start roscore, or set ROS_MASTER_URI to where it runs");
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  // Started here rather than by the first NodeHandle, so that the node does not shut down
  // for good when the last NodeHandle goes; roscpp shuts it down at exit.
  if (!ros::isStarted()) ros::start();
}

bool initialized() { return ros::isInitialized() && ros::isStarted(); }

// --- Node ---

Node::Node(const std::string& ns) : handle_(checked_namespace(ns)), spinner_(1, &queue_) {
  handle_.setCallbackQueue(&queue_);
  spinner_.start();
}

Node::~Node() {
  spinner_.stop();
  queue_.callAvailable(ros::WallDuration(0));
}

std::string Node::resolve(const std::string& name) const {
  try {
    return handle_.resolveName(name);
  } catch (const ros::Exception& e) {
    throw CorosError("'" + name + "' is not a ROS name: " + e.what());
  }
}

void Node::post(std::function<void()> fn) {
  queue_.addCallback(boost::make_shared<FunctionCallback>(std::move(fn)));
}

// --- PublishersManager ---

PublishersManager::Entry PublishersManager::find(const std::string& key) const {
  std::lock_guard lock(mutex_);
  const auto it = publishers_.find(key);
  if (it == publishers_.end()) {
    throw CorosError("no publisher under key '" + key + "' (add<Msg>(key, topic) first)");
  }
  return it->second;
}

bool PublishersManager::remove(const std::string& key) {
  ros::Publisher publisher;  // unadvertised outside the lock, when the last copy goes
  std::lock_guard lock(mutex_);
  const auto it = publishers_.find(key);
  if (it == publishers_.end()) return false;
  publisher = std::move(it->second.publisher);
  publishers_.erase(it);
  return true;
}

bool PublishersManager::has(const std::string& key) const {
  std::lock_guard lock(mutex_);
  return publishers_.contains(key);
}

std::string PublishersManager::topic(const std::string& key) const {
  return find(key).publisher.getTopic();
}

std::uint32_t PublishersManager::subscriber_count(const std::string& key) const {
  return find(key).publisher.getNumSubscribers();
}

// --- SubscribersManager ---

SubscribersManager::~SubscribersManager() {
  std::map<std::string, ros::Subscriber> subscribers;
  {
    std::lock_guard lock(mutex_);
    subscribers.swap(subscribers_);
  }
  // Each unsubscribes here, waiting for its callback if it is running.
}

ros::Subscriber SubscribersManager::find(const std::string& key) const {
  std::lock_guard lock(mutex_);
  const auto it = subscribers_.find(key);
  if (it == subscribers_.end()) {
    throw CorosError("no subscriber under key '" + key + "' (add<Msg>(key, topic, fn) first)");
  }
  return it->second;
}

bool SubscribersManager::remove(const std::string& key) {
  ros::Subscriber subscriber;
  {
    std::lock_guard lock(mutex_);
    const auto it = subscribers_.find(key);
    if (it == subscribers_.end()) return false;
    subscriber = std::move(it->second);
    subscribers_.erase(it);
  }
  // Outside the lock: shutting down waits for a running callback, which may use this manager.
  subscriber.shutdown();
  return true;
}

bool SubscribersManager::has(const std::string& key) const {
  std::lock_guard lock(mutex_);
  return subscribers_.contains(key);
}

std::string SubscribersManager::topic(const std::string& key) const { return find(key).getTopic(); }

std::uint32_t SubscribersManager::publisher_count(const std::string& key) const {
  return find(key).getNumPublishers();
}

// --- KnowledgePublisher ---

std::string KnowledgePublisher::neighborhood_topic(const std::string& agent_id) {
  // fmt, not "/" + std::string: GCC 12's -Wrestrict misfires on that at -O3.
  return fmt::format("/{}/neighborhood_list", ros_name(agent_id));
}

std::string KnowledgePublisher::task_states_topic(const std::string& agent_id) {
  return fmt::format("/{}/task_states", ros_name(agent_id));
}

struct KnowledgePublisher::Impl {
  Impl(Agent& a, KnowledgePublisherOptions o) : agent(a), options(o) {}

  icars_coros_msgs::NeighborhoodList neighborhood() {
    icars_coros_msgs::NeighborhoodList list;
    list.agent = agent.id();
    for (const AgentState& state : agent.neighbors().neighbors()) {
      icars_coros_msgs::Neighbor n;
      n.id = state.id;
      n.ip = state.ip;
      n.port = state.port;
      n.role = state.role;
      n.status = state.status;
      n.timestamp = state.timestamp;
      n.x = state.x;
      n.y = state.y;
      n.load = state.load;
      list.neighbors.push_back(std::move(n));
    }
    return list;
  }

  icars_coros_msgs::TaskStateList task_states() {
    icars_coros_msgs::TaskStateList list;
    list.agent = agent.id();
    for (const TaskState& state : agent.tasks().tasks()) {
      icars_coros_msgs::TaskState t;
      t.id = state.id;
      t.auctioneer = state.auctioneer;
      t.robot = state.robot;
      t.round = state.round;
      t.stage = std::string(to_string(state.stage));
      t.cost = state.cost;
      t.distance = state.distance;
      list.tasks.push_back(std::move(t));
    }
    return list;
  }

  // Publishes what changed (stamps aside), and everything once a period has passed.
  void publish(bool force) {
    const auto now = Clock::now();
    const bool due = force || now - last_sent >= options.period;
    auto neighbors = neighborhood();
    auto compared = neighbors;
    for (auto& n : compared.neighbors) n.timestamp = 0;  // every HELLO brings a new one
    if (due || !sent_neighbors || compared != *sent_neighbors) {
      sent_neighbors = std::move(compared);
      neighbors.stamp = Agent::wall_seconds();
      publishers.publish("neighborhood", neighbors);
    }
    auto tasks = task_states();
    if (due || !sent_tasks || tasks != *sent_tasks) {
      sent_tasks = tasks;
      tasks.stamp = Agent::wall_seconds();
      publishers.publish("tasks", tasks);
    }
    if (due) last_sent = now;
  }

  Agent& agent;
  KnowledgePublisherOptions options;
  Node node;
  PublishersManager publishers{node};
  std::optional<icars_coros_msgs::NeighborhoodList> sent_neighbors;  // timestamps zeroed
  std::optional<icars_coros_msgs::TaskStateList> sent_tasks;         // stamp zero
  Clock::time_point last_sent{};
  std::shared_ptr<Timer> timer;  // last: cancelled before the rest goes
};

KnowledgePublisher::KnowledgePublisher(Agent& agent, KnowledgePublisherOptions options) {
  if (!initialized()) init("coros_" + agent.id());
  impl_ = std::make_shared<Impl>(agent, options);
  impl_->publishers.add<icars_coros_msgs::NeighborhoodList>(
      "neighborhood", neighborhood_topic(agent.id()), 1, true);
  impl_->publishers.add<icars_coros_msgs::TaskStateList>("tasks", task_states_topic(agent.id()), 1,
                                                         true);
  // The monitors' listeners cannot be removed: they hold the state weakly. They run inside a
  // table update, so the publication is posted to run after it.
  std::weak_ptr<Impl> weak = impl_;
  auto publish_soon = [weak, &agent] {
    agent.post([weak] {
      if (auto impl = weak.lock()) impl->publish(false);
    });
  };
  agent.neighbors().on_change([publish_soon](const AgentState&, bool) { publish_soon(); });
  agent.tasks().on_change([publish_soon](const TaskState&) { publish_soon(); });
  impl_->timer = agent.every(options.check, [weak] {
    if (auto impl = weak.lock()) impl->publish(false);
  });
  impl_->publish(true);
}

KnowledgePublisher::~KnowledgePublisher() = default;

}  // namespace icars::coros::ros_layer

// The COROS ROS Interaction Layer (COROS 4.2): a thin layer over roscpp so that agents publish
// and subscribe to ROS topics without handling ROS themselves.
//
//   init()              ros::init and ros::start once per process, after checking the master
//   Node                a NodeHandle in a namespace with its own callback queue and spinner
//                       thread: callbacks of one node run one at a time, on that thread
//   PublishersManager   the paper's PublishingManager: publishers by key over one node
//   SubscribersManager  the paper's SubscriptionManager: subscribers by key over one node
//   KnowledgePublisher  an agent's knowledge base on ROS: /<agent>/neighborhood_list and
//                       /<agent>/task_states (icars_coros_msgs), latched
//
// Lifetimes: managers hold a reference to their Node and must be destroyed before it (declare
// the Node first). The managers are thread-safe; the Node's callbacks run on its spinner.
//
// C++20: Debian's ROS 1 message headers do not compile as C++20. The build regenerates the
// standard messages this layer uses (std_msgs String, Int32 and Header, geometry_msgs
// PoseStamped and its parts, nav_msgs Odometry) with the installed gencpp, and those copies
// shadow /usr/include; another standard message must be added to `std_messages` in
// src/coros/ros/CMakeLists.txt before it can be included.
#pragma once

#include <ros/callback_queue.h>
#include <ros/node_handle.h>
#include <ros/serialization.h>
#include <ros/spinner.h>

#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "icars/coros/messages.h"

// Debian's roscpp_serialization 0.7.2 serializes std::vector fields through
// std::allocator<T>::rebind, which C++20 removed (fixed upstream in ros/roscpp_core#124, not
// yet released in Debian). These specializations, chosen over the library's for the
// std::allocator every generated message uses, write the same bytes without rebind.
#if __cplusplus > 201703L
namespace ros::serialization::cxx20 {
template <typename T>
struct VectorSerializer {
  using VecType = std::vector<T>;
  template <typename Stream>
  static void write(Stream& stream, const VecType& v) {
    stream.next(static_cast<std::uint32_t>(v.size()));
    for (const T& item : v) stream.next(item);
  }
  template <typename Stream>
  static void read(Stream& stream, VecType& v) {
    std::uint32_t length = 0;
    stream.next(length);
    v.resize(length);
    for (T& item : v) stream.next(item);
  }
  static std::uint32_t serializedLength(const VecType& v) {
    std::uint32_t size = 4;
    for (const T& item : v) size += serializationLength(item);
    return size;
  }
};
}  // namespace ros::serialization::cxx20

namespace ros::serialization {
template <typename T>
struct VectorSerializer<T, std::allocator<T>, typename boost::disable_if<mt::IsFixedSize<T>>::type>
    : cxx20::VectorSerializer<T> {};
template <typename T>
struct VectorSerializer<T, std::allocator<T>, typename boost::enable_if<mt::IsSimple<T>>::type>
    : cxx20::VectorSerializer<T> {};
template <typename T>
struct VectorSerializer<
    T, std::allocator<T>,
    typename boost::enable_if<mpl::and_<mt::IsFixedSize<T>, mpl::not_<mt::IsSimple<T>>>>::type>
    : cxx20::VectorSerializer<T> {};
}  // namespace ros::serialization
#endif

namespace icars::coros {
class Agent;
}

namespace icars::coros::ros_layer {

// Initializes roscpp for this process as `node_name` (anonymous, no SIGINT handler) with the
// given name remappings, waits up to `master_wait` for the master at ROS_MASTER_URI and starts
// the node, which then lives until the process exits. Later calls only check that the master
// still answers (the first name and remappings stay). Throws CorosError when the master does
// not answer in time.
void init(const std::string& node_name, const std::map<std::string, std::string>& remappings = {},
          std::chrono::milliseconds master_wait = std::chrono::seconds(5));

// True once init() has succeeded in this process.
bool initialized();

// `text` as a ROS name component: characters other than letters, digits and '_' become '_',
// and a name not starting with a letter gets an 'n' in front ("robot-1" -> "robot_1"). Agent
// ids become node names and topic namespaces this way.
std::string ros_name(std::string_view text);

// A ROS node handle in namespace `ns` ("" for the node's own namespace, "/robot1", ...) whose
// subscriptions and timers run on one spinner thread of its own, started on construction and
// joined on destruction. Throws CorosError when init() has not run.
class Node {
 public:
  explicit Node(const std::string& ns = "");
  // Stops the spinner, then runs what post() queued and no spinner ran, on this thread.
  ~Node();
  Node(const Node&) = delete;
  Node& operator=(const Node&) = delete;

  ros::NodeHandle& handle() { return handle_; }
  const std::string& ns() const { return handle_.getNamespace(); }
  // The topic name `name` resolves to in this node ("odom" -> "/robot1/odom"); throws
  // CorosError for an invalid name.
  std::string resolve(const std::string& name) const;
  // Runs fn on the spinner thread, after the callbacks already queued; never inside post().
  void post(std::function<void()> fn);

 private:
  ros::CallbackQueue queue_;
  ros::NodeHandle handle_;
  ros::AsyncSpinner spinner_;
};

// Publishers by key (COROS PublishingManager). Thread-safe.
class PublishersManager {
 public:
  explicit PublishersManager(Node& node) : node_(node) {}
  PublishersManager(const PublishersManager&) = delete;
  PublishersManager& operator=(const PublishersManager&) = delete;

  // Advertises `topic` (resolved in the node's namespace) for messages of type Msg under
  // `key`. A latched publisher sends its last message to every subscriber that connects.
  // Throws CorosError when the key is taken or the topic name is invalid.
  template <class Msg>
  void add(const std::string& key, const std::string& topic, std::uint32_t queue = 10,
           bool latch = false);
  // Throws CorosError for an unknown key, or when Msg is not the key's message type.
  template <class Msg>
  void publish(const std::string& key, const Msg& message);
  bool remove(const std::string& key);  // true when the key was there
  bool has(const std::string& key) const;
  std::string topic(const std::string& key) const;  // resolved; throws for an unknown key
  std::uint32_t subscriber_count(const std::string& key) const;  // connected subscribers

 private:
  struct Entry {
    ros::Publisher publisher;
    std::string datatype;  // ROS message type, "geometry_msgs/PoseStamped"
  };
  Entry find(const std::string& key) const;
  Node& node_;
  mutable std::mutex mutex_;
  std::map<std::string, Entry> publishers_;
};

// Subscribers by key (COROS SubscriptionManager). Thread-safe; callbacks run on the node's
// spinner thread, one at a time.
class SubscribersManager {
 public:
  explicit SubscribersManager(Node& node) : node_(node) {}
  ~SubscribersManager();
  SubscribersManager(const SubscribersManager&) = delete;
  SubscribersManager& operator=(const SubscribersManager&) = delete;

  // Subscribes to `topic` (resolved in the node's namespace) under `key`. Throws CorosError
  // when the key is taken or the topic name is invalid.
  template <class Msg>
  void add(const std::string& key, const std::string& topic,
           std::function<void(const Msg&)> callback, std::uint32_t queue = 10);
  // Unsubscribes; once it returns, the callback is not running and never runs again (unless
  // called from that callback itself). True when the key was there.
  bool remove(const std::string& key);
  bool has(const std::string& key) const;
  std::string topic(const std::string& key) const;  // resolved; throws for an unknown key
  std::uint32_t publisher_count(const std::string& key) const;  // connected publishers

 private:
  ros::Subscriber find(const std::string& key) const;
  Node& node_;
  mutable std::mutex mutex_;
  std::map<std::string, ros::Subscriber> subscribers_;
};

struct KnowledgePublisherOptions {
  std::chrono::milliseconds period{1000};  // republish at least this often
  std::chrono::milliseconds check{100};    // look for changed entries this often
};

// Publishes an agent's neighbour and task tables (COROS State Monitoring) on the latched
// topics /<agent id>/neighborhood_list (icars_coros_msgs/NeighborhoodList) and
// /<agent id>/task_states (icars_coros_msgs/TaskStateList): at once when a neighbour joins or
// leaves or a task changes, when an entry changes (position, status, load), and at least
// every `period`. It reads the tables on the agent's thread, so construct and destroy it
// there (agent.call) or while the agent is not running (before start(), after stop()), and
// destroy it before the agent. Calls init() with a name from the agent id if needed.
class KnowledgePublisher {
 public:
  explicit KnowledgePublisher(Agent& agent, KnowledgePublisherOptions options = {});
  ~KnowledgePublisher();
  KnowledgePublisher(const KnowledgePublisher&) = delete;
  KnowledgePublisher& operator=(const KnowledgePublisher&) = delete;

  static std::string neighborhood_topic(const std::string& agent_id);  // "/<id>/neighborhood_list"
  static std::string task_states_topic(const std::string& agent_id);   // "/<id>/task_states"

 private:
  struct Impl;
  std::shared_ptr<Impl> impl_;  // shared with the monitors' listeners, which outlive this
};

// --- templates ---

template <class Msg>
void PublishersManager::add(const std::string& key, const std::string& topic, std::uint32_t queue,
                            bool latch) {
  std::lock_guard lock(mutex_);
  if (publishers_.contains(key)) {
    throw CorosError("publisher key '" + key + "' is already used (topic " +
                     publishers_.at(key).publisher.getTopic() + ")");
  }
  try {
    publishers_.emplace(key, Entry{node_.handle().advertise<Msg>(topic, queue, latch),
                                   ros::message_traits::datatype<Msg>()});
  } catch (const ros::Exception& e) {
    throw CorosError("cannot advertise '" + topic + "': " + e.what());
  }
}

template <class Msg>
void PublishersManager::publish(const std::string& key, const Msg& message) {
  const Entry entry = find(key);
  const std::string type = ros::message_traits::datatype<Msg>();
  if (type != entry.datatype) {
    throw CorosError("publisher '" + key + "' publishes " + entry.datatype + " on " +
                     entry.publisher.getTopic() + ", not " + type);
  }
  entry.publisher.publish(message);
}

template <class Msg>
void SubscribersManager::add(const std::string& key, const std::string& topic,
                             std::function<void(const Msg&)> callback, std::uint32_t queue) {
  std::lock_guard lock(mutex_);
  if (subscribers_.contains(key)) {
    throw CorosError("subscriber key '" + key + "' is already used (topic " +
                     subscribers_.at(key).getTopic() + ")");
  }
  ros::SubscribeOptions options;
  options.init<Msg>(
      topic, queue,
      [fn = std::move(callback)](const boost::shared_ptr<const Msg>& message) { fn(*message); });
  try {
    subscribers_.emplace(key, node_.handle().subscribe(options));
  } catch (const ros::Exception& e) {
    throw CorosError("cannot subscribe to '" + topic + "': " + e.what());
  }
}

}  // namespace icars::coros::ros_layer

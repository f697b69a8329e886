// peer: an independent DDS participant (eProsima Fast DDS, the middleware behind ROS 2's
// default RMW: 2.9 as Debian 12 ships it, or 3.1 as Debian 13 does, what Kilted and
// Lyrical use) that speaks a few ROS 2 message types on the wire, for the tests of
// chassis_sdk's ROS 2 bridge (which runs on Cyclone DDS). Built by
// tests/support/dds_peer.py from this file and fastddsgen's code for ros2_types.idl.
//
// Usage:
//   peer pub <kind> <dds_topic> [--rate HZ] [--count N] [--hold S] [--linear X]
//            [--angular Z] [--data true|false] [--frame ID] [--best-effort]
//            [--transient-local] [--domain N] [--unicast] [--wait-match S]
//       kind: twist | twist_stamped | bool | junk_twist (a Vector3_ sent under Twist_'s
//       type name: samples a reader cannot decode)
//       Waits up to --wait-match seconds (default 10) for a reader to match, publishes
//       --count samples (default 10) at --rate Hz (default 10), waits (up to 5 s) for a
//       reliable writer's samples to be acknowledged, keeps the writer alive and silent
//       for --hold seconds (default 0), then deletes the writer and the participant.
//       Twist: linear.x = --linear, angular.z = --angular (default 0; nan and inf are
//       taken, for the tests of refusals), the rest 0.
//       TwistStamped: the same, header.stamp = wall clock, header.frame_id = --frame
//       (default "base_link"). Bool: data = --data (default true).
//       Exit 0; 3 when no reader matched in time.
//   peer sub <kind> <dds_topic> [--duration S] [--count N] [--best-effort]
//            [--transient-local] [--domain N] [--unicast]
//       kind: twist | twist_stamped | bool | odometry | tf | battery | imu | graph |
//             string | joint_state
//       (graph: rmw_dds_common/ParticipantEntitiesInfo, what rmw publishes on
//       ros_discovery_info; subscribe to it with --transient-local, as rmw does)
//       Prints one line per sample received, for --duration seconds (default 10) or
//       until --count samples (default 0: no limit). Exit 0.
//
// QoS: RELIABLE (or BEST_EFFORT with --best-effort), VOLATILE (or TRANSIENT_LOCAL with
// --transient-local), KEEP_LAST 10: rclpy's default profile. Data sharing is off.
// Transport: UDPv4 only (no shared memory), so that the peer and the Cyclone DDS stack
// under test really talk RTPS over UDP. Default discovery: SPDP multicast (239.255.0.1).
// --unicast: no multicast at all; the participant listens on 127.0.0.1 only and
// announces itself to 127.0.0.1 (initial peers: the well-known unicast ports of
// participant indices 0..9 of the domain). --domain: the DDS domain (ROS_DOMAIN_ID's
// meaning; default 0, the environment is not read).
// The participant's USER_DATA is "enclave=/;", as ROS 2's rmw sets it.
//
// Output: one JSON object a line on stdout, flushed; "t" is the wall clock (s, float).
//   {"event":"started","t":..,"mode":"pub","kind":..,"topic":..,"type":..}
//   {"event":"participant","t":..,"status":"discovered"|"removed"|..,"name":..,
//    "guid":HEX}                                  a remote participant (16-byte GUID, hex)
//   {"event":"endpoint","t":..,"entity":"reader"|"writer","status":"discovered"|..,
//    "topic":..,"guid":HEX}                       a remote reader or writer (any topic)
//   {"event":"matched","t":..,"count":N}          a reader (pub) / writer (sub) matched
//   {"event":"unmatched","t":..,"count":N}        one went away
//   {"event":"incompatible_qos","t":..,"policy":ID} a remote endpoint was refused
//   {"event":"published","i":k,"t":..}            pub: sample k (0-based) written
//   {"event":"no_match","t":..}                   pub: nobody matched in time (exit 3)
//   {"event":"acked","t":..,"ok":true|false}      pub: reliable samples acknowledged
//   {"event":"deleting_writer","t":..}            pub: just before the writer is deleted
//   {"event":"writer_deleted","t":..}             pub: writer and participant deleted
//   {"event":"sample","t":..,<fields>}            sub: one sample (fields per kind)
//   {"event":"done","t":..,"samples":N}           sub: finished
//   {"event":"interrupted","t":..,"signal":S}     SIGINT/SIGTERM: entities deleted first
// Errors go to stderr, exit 2 (usage) or 1.

#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/domain/DomainParticipantListener.hpp>
#include <fastdds/dds/domain/qos/DomainParticipantQos.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/DataWriterListener.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/publisher/qos/DataWriterQos.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/subscriber/qos/DataReaderQos.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>

// Fast DDS 3 (ROS 2 Kilted and Lyrical; Debian 13) and 2 (Debian 12's 2.9): the same
// peer, built against either. Fast DDS 3 folded eprosima::fastrtps into
// eprosima::fastdds, renamed its headers .hpp, and fastddsgen 4 does the same.
#if __has_include(<fastdds/config.hpp>)
#include <fastdds/config.hpp>
#endif
#if defined(FASTDDS_VERSION_MAJOR) && FASTDDS_VERSION_MAJOR >= 3
#define PEER_FASTDDS3 1
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.hpp>
#include <fastdds/utils/IPLocator.hpp>

#include "ros2_types.hpp"
#include "ros2_typesPubSubTypes.hpp"
namespace rtps = eprosima::fastdds::rtps;
using Duration = eprosima::fastdds::dds::Duration_t;
static constexpr auto RETURN_OK = eprosima::fastdds::dds::RETCODE_OK;
#else
#define PEER_FASTDDS3 0
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastrtps/utils/IPLocator.h>

#include "ros2_types.h"
#include "ros2_typesPubSubTypes.h"
namespace rtps = eprosima::fastrtps::rtps;
using Duration = eprosima::fastrtps::Duration_t;
static const auto RETURN_OK = eprosima::fastrtps::types::ReturnCode_t::RETCODE_OK;
#endif

using namespace eprosima::fastdds::dds;
using eprosima::fastdds::rtps::UDPv4TransportDescriptor;
using rtps::IPLocator;
using rtps::Locator_t;

namespace bi = builtin_interfaces::msg::dds_;
namespace gm = geometry_msgs::msg::dds_;
namespace nm = nav_msgs::msg::dds_;
namespace sm = sensor_msgs::msg::dds_;
namespace stdm = std_msgs::msg::dds_;
namespace tf = tf2_msgs::msg::dds_;
namespace rmw = rmw_dds_common::msg::dds_;

// ---------------------------------------------------------------------------------------
// Output

static std::mutex out_mutex;
static std::atomic<int> stop_signal{0};

static void on_signal(int sig) { stop_signal = sig; }

static double wall_now()
{
    using namespace std::chrono;
    return duration_cast<duration<double>>(system_clock::now().time_since_epoch()).count();
}

// The shortest text that reads back as the same value; JSON has no NaN or infinities.
static std::string number(double v, bool single)
{
    if (!std::isfinite(v)) {
        return "null";
    }
    char buf[40];
    for (int precision = single ? 6 : 15; precision <= 17; ++precision) {
        std::snprintf(buf, sizeof buf, "%.*g", precision, v);
        if (single ? std::strtof(buf, nullptr) == static_cast<float>(v)
                   : std::strtod(buf, nullptr) == v) {
            break;
        }
    }
    return buf;
}

static std::string quoted(const std::string& s)
{
    std::string out = "\"";
    for (unsigned char c : s) {
        if (c == '"' || c == '\\') {
            out += '\\';
            out += static_cast<char>(c);
        } else if (c < 0x20) {
            char buf[8];
            std::snprintf(buf, sizeof buf, "\\u%04x", c);
            out += buf;
        } else {
            out += static_cast<char>(c);
        }
    }
    return out + "\"";
}

// A JSON object, built field by field.
class Json
{
public:
    Json& raw(const char* key, const std::string& value)
    {
        body_ += body_.empty() ? "" : ",";
        body_ += quoted(key) + ":" + value;
        return *this;
    }
    Json& num(const char* key, double v) { return raw(key, number(v, false)); }
    Json& num32(const char* key, float v) { return raw(key, number(v, true)); }
    Json& integer(const char* key, long long v) { return raw(key, std::to_string(v)); }
    Json& str(const char* key, const std::string& v) { return raw(key, quoted(v)); }
    Json& boolean(const char* key, bool v) { return raw(key, v ? "true" : "false"); }
    Json& obj(const char* key, const Json& v) { return raw(key, v.text()); }
    std::string text() const { return "{" + body_ + "}"; }

private:
    std::string body_;
};

template <class Seq>
static std::string array(const Seq& values, bool single)
{
    std::string out = "[";
    for (const auto& v : values) {
        out += (out.size() > 1 ? "," : "") + number(v, single);
    }
    return out + "]";
}

static Json event(const char* name)
{
    Json j;
    j.str("event", name).num("t", wall_now());
    return j;
}

static void emit(const Json& j)
{
    std::lock_guard<std::mutex> lock(out_mutex);
    std::fputs(j.text().c_str(), stdout);
    std::fputc('\n', stdout);
    std::fflush(stdout);
}

// ---------------------------------------------------------------------------------------
// The messages, as JSON

static Json vec3(const gm::Vector3_& v)
{
    Json j;
    return j.num("x", v.x()).num("y", v.y()).num("z", v.z());
}

static Json point(const gm::Point_& v)
{
    Json j;
    return j.num("x", v.x()).num("y", v.y()).num("z", v.z());
}

static Json quat(const gm::Quaternion_& q)
{
    Json j;
    return j.num("x", q.x()).num("y", q.y()).num("z", q.z()).num("w", q.w());
}

static Json stamp(const bi::Time_& t)
{
    Json j;
    return j.integer("sec", t.sec()).integer("nanosec", t.nanosec());
}

static void header(Json& j, const stdm::Header_& h)
{
    j.obj("stamp", stamp(h.stamp())).str("frame_id", h.frame_id());
}

static std::string hex(const unsigned char* bytes, size_t n)
{
    static const char digits[] = "0123456789abcdef";
    std::string out;
    for (size_t i = 0; i < n; ++i) {
        out += digits[bytes[i] >> 4];
        out += digits[bytes[i] & 15];
    }
    return out;
}

static std::string hex(const rtps::GUID_t& g)
{
    unsigned char bytes[16];
    std::memcpy(bytes, g.guidPrefix.value, 12);
    std::memcpy(bytes + 12, g.entityId.value, 4);
    return hex(bytes, 16);
}

static std::string gids(const std::vector<rmw::Gid_>& seq)
{
    std::string out = "[";
    for (const auto& g : seq) {
        out += (out.size() > 1 ? "," : "") + quoted(hex(g.data().data(), g.data().size()));
    }
    return out + "]";
}

static void describe(Json& j, const rmw::ParticipantEntitiesInfo_& m)
{
    j.str("gid", hex(m.gid().data().data(), m.gid().data().size()));
    std::string nodes = "[";
    for (const auto& n : m.node_entities_info_seq()) {
        Json node;
        node.str("namespace", n.node_namespace().to_string())
            .str("name", n.node_name().to_string())
            .raw("readers", gids(n.reader_gid_seq()))
            .raw("writers", gids(n.writer_gid_seq()));
        nodes += (nodes.size() > 1 ? "," : "") + node.text();
    }
    j.raw("nodes", nodes + "]");
}

static void describe(Json& j, const gm::Twist_& m)
{
    j.obj("linear", vec3(m.linear())).obj("angular", vec3(m.angular()));
}

static void describe(Json& j, const gm::TwistStamped_& m)
{
    header(j, m.header());
    describe(j, m.twist());
}

static void describe(Json& j, const stdm::Bool_& m) { j.boolean("data", m.data()); }

static void describe(Json& j, const stdm::String_& m) { j.str("data", m.data()); }

static void describe(Json& j, const sm::JointState_& m)
{
    header(j, m.header());
    std::string names = "[";
    for (const auto& n : m.name()) {
        names += (names.size() > 1 ? "," : "") + quoted(n);
    }
    j.raw("name", names + "]")
        .raw("position", array(m.position(), false))
        .raw("velocity", array(m.velocity(), false))
        .raw("effort", array(m.effort(), false));
}

static void describe(Json& j, const nm::Odometry_& m)
{
    header(j, m.header());
    j.str("child_frame_id", m.child_frame_id())
        .obj("position", point(m.pose().pose().position()))
        .obj("orientation", quat(m.pose().pose().orientation()))
        .raw("pose_covariance", array(m.pose().covariance(), false))
        .obj("linear", vec3(m.twist().twist().linear()))
        .obj("angular", vec3(m.twist().twist().angular()))
        .raw("twist_covariance", array(m.twist().covariance(), false));
}

static void describe(Json& j, const tf::TFMessage_& m)
{
    std::string list = "[";
    for (const auto& t : m.transforms()) {
        Json one;
        header(one, t.header());
        one.str("child_frame_id", t.child_frame_id())
            .obj("translation", vec3(t.transform().translation()))
            .obj("rotation", quat(t.transform().rotation()));
        list += (list.size() > 1 ? "," : "") + one.text();
    }
    j.raw("transforms", list + "]");
}

static void describe(Json& j, const sm::BatteryState_& m)
{
    header(j, m.header());
    j.num32("voltage", m.voltage())
        .num32("temperature", m.temperature())
        .num32("current", m.current())
        .num32("charge", m.charge())
        .num32("capacity", m.capacity())
        .num32("design_capacity", m.design_capacity())
        .num32("percentage", m.percentage())
        .integer("power_supply_status", m.power_supply_status())
        .integer("power_supply_health", m.power_supply_health())
        .integer("power_supply_technology", m.power_supply_technology())
        .boolean("present", m.present())
        .raw("cell_voltage", array(m.cell_voltage(), true))
        .raw("cell_temperature", array(m.cell_temperature(), true))
        .str("location", m.location())
        .str("serial_number", m.serial_number());
}

static void describe(Json& j, const sm::Imu_& m)
{
    header(j, m.header());
    j.obj("orientation", quat(m.orientation()))
        .raw("orientation_covariance", array(m.orientation_covariance(), false))
        .obj("angular_velocity", vec3(m.angular_velocity()))
        .raw("angular_velocity_covariance", array(m.angular_velocity_covariance(), false))
        .obj("linear_acceleration", vec3(m.linear_acceleration()))
        .raw("linear_acceleration_covariance",
             array(m.linear_acceleration_covariance(), false));
}

// ---------------------------------------------------------------------------------------
// Options

struct Options
{
    std::string mode, kind, topic;
    double rate = 10.0;
    long count = -1;  // pub: 10, sub: 0 (no limit) unless given
    double hold = 0.0;
    double linear = 0.0;
    double angular = 0.0;
    bool data = true;
    std::string frame = "base_link";
    bool best_effort = false;
    bool transient_local = false;
    int domain = 0;
    bool unicast = false;
    double wait_match = 10.0;
    double duration = 10.0;
};

[[noreturn]] static void usage(const std::string& why)
{
    std::fprintf(stderr,
                 "peer: %s\n"
                 "usage: peer pub twist|twist_stamped|bool|junk_twist TOPIC [--rate HZ] [--count N] "
                 "[--hold S] [--linear X] [--angular Z] [--data true|false] [--frame ID] "
                 "[--best-effort] [--transient-local] [--domain N] [--unicast] "
                 "[--wait-match S]\n"
                 "       peer sub twist|twist_stamped|bool|odometry|tf|battery|imu TOPIC "
                 "[--duration S] [--count N] [--best-effort] [--transient-local] "
                 "[--domain N] [--unicast]\n",
                 why.c_str());
    std::exit(2);
}

// A value to publish may be NaN or infinite (the bridge must refuse those); a setting
// of the peer's own must be finite.
static double to_number(const std::string& option, const std::string& text,
                        bool any_double = false)
{
    char* end = nullptr;
    double v = std::strtod(text.c_str(), &end);
    if (text.empty() || *end != '\0' || (!any_double && !std::isfinite(v))) {
        usage(option + " wants a number, not '" + text + "'");
    }
    return v;
}

static Options parse(int argc, char** argv)
{
    if (argc < 4) {
        usage("mode, kind and topic are required");
    }
    Options o;
    o.mode = argv[1];
    o.kind = argv[2];
    o.topic = argv[3];
    const bool pub = o.mode == "pub";
    if (!pub && o.mode != "sub") {
        usage("mode is pub or sub, not '" + o.mode + "'");
    }
    for (int i = 4; i < argc; ++i) {
        const std::string a = argv[i];
        auto value = [&]() -> std::string {
            if (i + 1 >= argc) {
                usage(a + " wants a value");
            }
            return argv[++i];
        };
        auto pub_only = [&]() {
            if (!pub) {
                usage(a + " is for pub only");
            }
        };
        auto sub_only = [&]() {
            if (pub) {
                usage(a + " is for sub only");
            }
        };
        if (a == "--count") {
            double v = to_number(a, value());
            if (v < 0 || v != std::floor(v)) {
                usage("--count wants a whole number >= 0");
            }
            o.count = static_cast<long>(v);
        } else if (a == "--best-effort") {
            o.best_effort = true;
        } else if (a == "--transient-local") {
            o.transient_local = true;
        } else if (a == "--domain") {
            double v = to_number(a, value());
            if (v < 0 || v > 232 || v != std::floor(v)) {
                usage("--domain wants 0..232");
            }
            o.domain = static_cast<int>(v);
        } else if (a == "--unicast") {
            o.unicast = true;
        } else if (a == "--rate") {
            pub_only();
            o.rate = to_number(a, value());
            if (o.rate <= 0) {
                usage("--rate wants a positive number");
            }
        } else if (a == "--hold") {
            pub_only();
            o.hold = to_number(a, value());
        } else if (a == "--linear") {
            pub_only();
            o.linear = to_number(a, value(), true);
        } else if (a == "--angular") {
            pub_only();
            o.angular = to_number(a, value(), true);
        } else if (a == "--data") {
            pub_only();
            const std::string v = value();
            if (v != "true" && v != "false") {
                usage("--data is true or false");
            }
            o.data = v == "true";
        } else if (a == "--frame") {
            pub_only();
            o.frame = value();
        } else if (a == "--wait-match") {
            pub_only();
            o.wait_match = to_number(a, value());
        } else if (a == "--duration") {
            sub_only();
            o.duration = to_number(a, value());
        } else {
            usage("unknown option '" + a + "'");
        }
    }
    if (o.count < 0) {
        o.count = pub ? 10 : 0;
    }
    return o;
}

// ---------------------------------------------------------------------------------------
// Entities

class ParticipantWatcher : public DomainParticipantListener
{
public:
#if PEER_FASTDDS3
    void on_participant_discovery(DomainParticipant*, rtps::ParticipantDiscoveryStatus reason,
        const ParticipantBuiltinTopicData& info, bool& should_be_ignored) override
    {
        should_be_ignored = false;
        const auto& ud = info.user_data.data_vec();
        report(reason, info.participant_name.to_string(), std::string(ud.begin(), ud.end()),
            hex(info.guid));
    }
    void on_data_reader_discovery(DomainParticipant*, rtps::ReaderDiscoveryStatus reason,
        const SubscriptionBuiltinTopicData& info, bool& should_be_ignored) override
    {
        should_be_ignored = false;
        endpoint("reader", reason, info.topic_name.to_string(), hex(info.guid));
    }
    void on_data_writer_discovery(DomainParticipant*, rtps::WriterDiscoveryStatus reason,
        const PublicationBuiltinTopicData& info, bool& should_be_ignored) override
    {
        should_be_ignored = false;
        endpoint("writer", reason, info.topic_name.to_string(), hex(info.guid));
    }
#else
    void on_participant_discovery(
        DomainParticipant*, rtps::ParticipantDiscoveryInfo&& info) override
    {
        const auto& ud = info.info.m_userData;
        report(info.status, info.info.m_participantName.to_string(),
            std::string(ud.begin(), ud.end()), hex(info.info.m_guid));
    }
    void on_subscriber_discovery(DomainParticipant*, rtps::ReaderDiscoveryInfo&& info) override
    {
        endpoint("reader", info.status, info.info.topicName().to_string(), hex(info.info.guid()));
    }
    void on_publisher_discovery(DomainParticipant*, rtps::WriterDiscoveryInfo&& info) override
    {
        endpoint("writer", info.status, info.info.topicName().to_string(), hex(info.info.guid()));
    }
#endif

private:
    template <class Status>
    static void report(
        Status reason, const std::string& name, const std::string& user_data, const std::string& guid)
    {
        const char* status = "changed";
        switch (reason) {
        case Status::DISCOVERED_PARTICIPANT: status = "discovered"; break;
        case Status::REMOVED_PARTICIPANT: status = "removed"; break;
        case Status::DROPPED_PARTICIPANT: status = "dropped"; break;
        default: break;
        }
        emit(event("participant")
                 .str("status", status)
                 .str("name", name)
                 .str("user_data", user_data)
                 .str("guid", guid));
    }

    // Discovered (0), changed (1), removed (2) or ignored (3), in both versions' order.
    template <class Status>
    static void endpoint(const char* entity, Status reason, const std::string& topic,
        const std::string& guid)
    {
        static const char* names[] = {"discovered", "changed", "removed", "ignored"};
        const auto i = static_cast<unsigned>(reason);
        emit(event("endpoint")
                 .str("entity", entity)
                 .str("status", i < 4 ? names[i] : "other")
                 .str("topic", topic)
                 .str("guid", guid));
    }
};

// Counts matches; main waits on it.
struct Matches
{
    std::mutex mutex;
    std::condition_variable changed;
    int current = 0;

    void update(int count, int change)
    {
        {
            std::lock_guard<std::mutex> lock(mutex);
            current = count;
        }
        changed.notify_all();
        emit(event(change > 0 ? "matched" : "unmatched").integer("count", count));
    }
};

class WriterWatcher : public DataWriterListener
{
public:
    Matches matches;

    void on_publication_matched(DataWriter*, const PublicationMatchedStatus& s) override
    {
        matches.update(s.current_count, s.current_count_change);
    }
    void on_offered_incompatible_qos(DataWriter*, const OfferedIncompatibleQosStatus& s) override
    {
        emit(event("incompatible_qos").integer("policy", s.last_policy_id));
    }
};

static DomainParticipant* make_participant(const Options& o, DomainParticipantListener* listener)
{
    DomainParticipantQos q = PARTICIPANT_QOS_DEFAULT;
    q.name("chassis_sdk_dds_peer");
    const std::string enclave = "enclave=/;";
    q.user_data().data_vec(std::vector<rtps::octet>(enclave.begin(), enclave.end()));
    // No shared memory, no data sharing: RTPS over UDPv4 only.
    q.transport().use_builtin_transports = false;
    auto udp = std::make_shared<UDPv4TransportDescriptor>();
    if (o.unicast) {
        udp->interfaceWhiteList.emplace_back("127.0.0.1");
        // Announce to the well-known ports of participant indices 0..9 (Fast DDS's default
        // is 0..3; Cyclone DDS's automatic indices go up to 9).
        udp->maxInitialPeersRange = 10;
        Locator_t localhost;
        localhost.kind = LOCATOR_KIND_UDPv4;
        IPLocator::setIPv4(localhost, 127, 0, 0, 1);
        localhost.port = 0;  // port 0: the well-known ports, from the domain and index
        auto& builtin = q.wire_protocol().builtin;
        builtin.initialPeersList.clear();
        builtin.initialPeersList.push_back(localhost);
        builtin.metatrafficUnicastLocatorList.clear();
        builtin.metatrafficUnicastLocatorList.push_back(localhost);
        builtin.metatrafficMulticastLocatorList.clear();
        builtin.avoid_builtin_multicast = true;
        q.wire_protocol().default_unicast_locator_list.clear();
        q.wire_protocol().default_unicast_locator_list.push_back(localhost);
        q.wire_protocol().default_multicast_locator_list.clear();
    }
    q.transport().user_transports.push_back(udp);
    DomainParticipant* p = DomainParticipantFactory::get_instance()->create_participant(
        static_cast<DomainId_t>(o.domain), q, listener, StatusMask::none());
    if (p == nullptr) {
        std::fprintf(stderr, "peer: could not create the participant (domain %d)\n", o.domain);
        std::exit(1);
    }
    return p;
}

template <class Qos>
static void endpoint_qos(Qos& q, const Options& o)
{
    q.reliability().kind = o.best_effort ? BEST_EFFORT_RELIABILITY_QOS : RELIABLE_RELIABILITY_QOS;
    q.durability().kind = o.transient_local ? TRANSIENT_LOCAL_DURABILITY_QOS : VOLATILE_DURABILITY_QOS;
    q.history().kind = KEEP_LAST_HISTORY_QOS;
    q.history().depth = 10;
    q.data_sharing().off();
    // Unbounded strings and sequences: let the history grow past fastddsgen's bounds.
    q.endpoint().history_memory_policy = rtps::PREALLOCATED_WITH_REALLOC_MEMORY_MODE;
}

static void teardown(DomainParticipant* p)
{
    p->delete_contained_entities();
    DomainParticipantFactory::get_instance()->delete_participant(p);
}

// Sleeps until `deadline`, or until a signal: false on a signal.
template <class Clock>
static bool sleep_until(typename Clock::time_point deadline)
{
    while (Clock::now() < deadline) {
        if (stop_signal != 0) {
            return false;
        }
        auto left = deadline - Clock::now();
        std::this_thread::sleep_for(std::min<typename Clock::duration>(
            left, std::chrono::duration_cast<typename Clock::duration>(std::chrono::milliseconds(20))));
    }
    return stop_signal == 0;
}

static int interrupted()
{
    emit(event("interrupted").integer("signal", stop_signal));
    return 128 + stop_signal;
}

static std::chrono::steady_clock::duration seconds(double s)
{
    return std::chrono::duration_cast<std::chrono::steady_clock::duration>(
        std::chrono::duration<double>(s < 0 ? 0 : s));
}

// ---------------------------------------------------------------------------------------
// pub

static void fill(gm::Twist_& m, const Options& o)
{
    m.linear().x(o.linear);
    m.angular().z(o.angular);
}

static void fill(gm::TwistStamped_& m, const Options& o)
{
    const double now = wall_now();
    double sec = std::floor(now);
    auto nanosec = static_cast<uint32_t>((now - sec) * 1e9);
    if (nanosec >= 1000000000u) {
        nanosec = 999999999u;
    }
    m.header().stamp().sec(static_cast<int32_t>(sec));
    m.header().stamp().nanosec(nanosec);
    m.header().frame_id(o.frame);
    fill(m.twist(), o);
}

static void fill(stdm::Bool_& m, const Options& o) { m.data(o.data); }

// junk_twist: a Vector3_ (24 bytes) under Twist_'s type name (48 bytes), which a reader
// that matches by name cannot decode: a hostile writer's samples.
static void fill(gm::Vector3_& m, const Options& o) { m.x(o.linear); }

template <class T, class PubSubType>
static int run_pub(const Options& o, const char* type_name = nullptr)
{
    using Clock = std::chrono::steady_clock;
    ParticipantWatcher pw;
    DomainParticipant* p = make_participant(o, &pw);
    TypeSupport type(new PubSubType());
    const std::string name = type_name != nullptr ? type_name : type.get_type_name();
    type.register_type(p, name);
    Topic* topic = p->create_topic(o.topic, name, TOPIC_QOS_DEFAULT);
    Publisher* publisher = p->create_publisher(PUBLISHER_QOS_DEFAULT);
    DataWriterQos wq = DATAWRITER_QOS_DEFAULT;
    endpoint_qos(wq, o);
    WriterWatcher ww;
    DataWriter* writer = topic && publisher
                             ? publisher->create_datawriter(topic, wq, &ww, StatusMask::all())
                             : nullptr;
    if (writer == nullptr) {
        std::fprintf(stderr, "peer: could not create the writer on '%s'\n", o.topic.c_str());
        teardown(p);
        return 1;
    }
    emit(event("started")
             .str("mode", "pub")
             .str("kind", o.kind)
             .str("topic", o.topic)
             .str("type", type.get_type_name()));

    const auto give_up = Clock::now() + seconds(o.wait_match);
    bool matched = false;
    while (stop_signal == 0) {
        std::unique_lock<std::mutex> lock(ww.matches.mutex);
        if (ww.matches.current > 0) {
            matched = true;
            break;
        }
        if (Clock::now() >= give_up) {
            break;
        }
        ww.matches.changed.wait_for(lock, std::chrono::milliseconds(20));
    }
    if (stop_signal != 0) {
        teardown(p);
        return interrupted();
    }
    if (!matched) {
        emit(event("no_match"));
        teardown(p);
        return 3;
    }

    const auto period = seconds(1.0 / o.rate);
    auto next = Clock::now();
    for (long i = 0; i < o.count; ++i) {
        if (i > 0 && !sleep_until<Clock>(next)) {
            teardown(p);
            return interrupted();
        }
        T sample;
        fill(sample, o);
        if (!writer->write(&sample)) {
            std::fprintf(stderr, "peer: write %ld failed\n", i);
        }
        emit(event("published").integer("i", i));
        next += period;
    }
    if (!o.best_effort && o.count > 0) {
        const bool ok =
            writer->wait_for_acknowledgments(Duration(5, 0)) == RETURN_OK;
        emit(event("acked").boolean("ok", ok));
    }
    if (!sleep_until<Clock>(Clock::now() + seconds(o.hold))) {
        teardown(p);
        return interrupted();
    }
    emit(event("deleting_writer"));  // the moment it starts to go: what a stop is timed from
    publisher->delete_datawriter(writer);
    teardown(p);
    emit(event("writer_deleted"));
    return 0;
}

// ---------------------------------------------------------------------------------------
// sub

template <class T>
class ReaderWatcher : public DataReaderListener
{
public:
    explicit ReaderWatcher(long limit) : limit_(limit) {}

    void on_subscription_matched(DataReader*, const SubscriptionMatchedStatus& s) override
    {
        matches.update(s.current_count, s.current_count_change);
    }

    void on_requested_incompatible_qos(DataReader*, const RequestedIncompatibleQosStatus& s) override
    {
        emit(event("incompatible_qos").integer("policy", s.last_policy_id));
    }

    void on_data_available(DataReader* reader) override
    {
        T sample;
        SampleInfo info;
        while (reader->take_next_sample(&sample, &info) == RETURN_OK) {
            if (!info.valid_data) {
                continue;
            }
            {
                std::lock_guard<std::mutex> lock(mutex_);
                if (limit_ > 0 && received_ >= limit_) {
                    continue;
                }
                ++received_;
            }
            Json j = event("sample");
            describe(j, sample);
            emit(j);
            done_.notify_all();
        }
    }

    // Waits until the limit, the deadline or a signal; the number of samples taken.
    long wait(std::chrono::steady_clock::time_point deadline)
    {
        std::unique_lock<std::mutex> lock(mutex_);
        while (stop_signal == 0 && std::chrono::steady_clock::now() < deadline &&
               !(limit_ > 0 && received_ >= limit_)) {
            done_.wait_for(lock, std::chrono::milliseconds(20));
        }
        return received_;
    }

    Matches matches;

private:
    std::mutex mutex_;
    std::condition_variable done_;
    long limit_;
    long received_ = 0;
};

template <class T, class PubSubType>
static int run_sub(const Options& o)
{
    ParticipantWatcher pw;
    DomainParticipant* p = make_participant(o, &pw);
    TypeSupport type(new PubSubType());
    type.register_type(p);
    Topic* topic = p->create_topic(o.topic, type.get_type_name(), TOPIC_QOS_DEFAULT);
    Subscriber* subscriber = p->create_subscriber(SUBSCRIBER_QOS_DEFAULT);
    DataReaderQos rq = DATAREADER_QOS_DEFAULT;
    endpoint_qos(rq, o);
    ReaderWatcher<T> rw(o.count);
    const auto deadline = std::chrono::steady_clock::now() + seconds(o.duration);
    DataReader* reader = topic && subscriber
                             ? subscriber->create_datareader(topic, rq, &rw, StatusMask::all())
                             : nullptr;
    if (reader == nullptr) {
        std::fprintf(stderr, "peer: could not create the reader on '%s'\n", o.topic.c_str());
        teardown(p);
        return 1;
    }
    emit(event("started")
             .str("mode", "sub")
             .str("kind", o.kind)
             .str("topic", o.topic)
             .str("type", type.get_type_name()));
    const long n = rw.wait(deadline);
    // Stop the callbacks before the listener goes.
    reader->set_listener(nullptr);
    teardown(p);
    if (stop_signal != 0) {
        return interrupted();
    }
    emit(event("done").integer("samples", n));
    return 0;
}

// ---------------------------------------------------------------------------------------

int main(int argc, char** argv)
{
    const Options o = parse(argc, argv);
    std::signal(SIGINT, on_signal);
    std::signal(SIGTERM, on_signal);
    if (o.mode == "pub") {
        if (o.kind == "twist") return run_pub<gm::Twist_, gm::Twist_PubSubType>(o);
        if (o.kind == "twist_stamped") return run_pub<gm::TwistStamped_, gm::TwistStamped_PubSubType>(o);
        if (o.kind == "bool") return run_pub<stdm::Bool_, stdm::Bool_PubSubType>(o);
        if (o.kind == "junk_twist") {
            return run_pub<gm::Vector3_, gm::Vector3_PubSubType>(o, "geometry_msgs::msg::dds_::Twist_");
        }
        usage("pub kind is twist, twist_stamped, bool or junk_twist, not '" + o.kind + "'");
    }
    if (o.kind == "twist") return run_sub<gm::Twist_, gm::Twist_PubSubType>(o);
    if (o.kind == "twist_stamped") return run_sub<gm::TwistStamped_, gm::TwistStamped_PubSubType>(o);
    if (o.kind == "bool") return run_sub<stdm::Bool_, stdm::Bool_PubSubType>(o);
    if (o.kind == "odometry") return run_sub<nm::Odometry_, nm::Odometry_PubSubType>(o);
    if (o.kind == "tf") return run_sub<tf::TFMessage_, tf::TFMessage_PubSubType>(o);
    if (o.kind == "battery") return run_sub<sm::BatteryState_, sm::BatteryState_PubSubType>(o);
    if (o.kind == "imu") return run_sub<sm::Imu_, sm::Imu_PubSubType>(o);
    if (o.kind == "string") return run_sub<stdm::String_, stdm::String_PubSubType>(o);
    if (o.kind == "joint_state") return run_sub<sm::JointState_, sm::JointState_PubSubType>(o);
    if (o.kind == "graph") {
        return run_sub<rmw::ParticipantEntitiesInfo_, rmw::ParticipantEntitiesInfo_PubSubType>(o);
    }
    usage("sub kind is twist, twist_stamped, bool, odometry, tf, battery, imu, graph, string or joint_state, not '" + o.kind + "'");
}

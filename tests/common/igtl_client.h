// An OpenIGTLink client for tests, built from the same library as the server: connects on
// loopback, sends the device messages of docs/devices.md and reads the force messages back.
#pragma once

#include <igtlClientSocket.h>
#include <igtlMessageHeader.h>
#include <igtlSensorMessage.h>
#include <igtlStringMessage.h>
#include <igtlTransformMessage.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

namespace vcsim::test {

class IgtlClient {
 public:
  using Clock = std::chrono::steady_clock;

  // Tries to connect to 127.0.0.1:port for up to `patience` (the server may still be starting).
  bool connect(int port, std::chrono::milliseconds patience = std::chrono::milliseconds(2000)) {
    const auto end = Clock::now() + patience;
    do {
      sock_ = igtl::ClientSocket::New();
      if (sock_->ConnectToServer("127.0.0.1", port) == 0) {
        sock_->SetReceiveTimeout(200);
        return true;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    } while (Clock::now() < end);
    return false;
  }
  void close() { sock_->CloseSocket(); }

  bool send_raw(const void* p, int n) { return sock_->Send(p, n) == 1; }

  static igtl::SensorMessage::Pointer sensor(const char* name, const std::vector<double>& values) {
    auto msg = igtl::SensorMessage::New();
    msg->SetDeviceName(name);
    msg->SetLength(static_cast<unsigned int>(values.size()));
    for (unsigned int i = 0; i < values.size(); ++i) msg->SetValue(i, values[i]);
    msg->Pack();
    return msg;
  }
  bool send_sensor(const char* name, const std::vector<double>& values) {
    auto msg = sensor(name, values);
    return send_raw(msg->GetPackPointer(), msg->GetPackSize());
  }

  // A STRING message, e.g. an exchange request on device "exchange" (docs/devices.md).
  bool send_string(const char* name, const std::string& text) {
    auto msg = igtl::StringMessage::New();
    msg->SetDeviceName(name);
    msg->SetString(text.c_str());
    msg->Pack();
    return send_raw(msg->GetPackPointer(), msg->GetPackSize());
  }

  // Reads messages until a STRING named `name` arrives; false on timeout or a closed socket.
  bool read_string(const std::string& name, std::string& text,
                   std::chrono::milliseconds limit = std::chrono::milliseconds(2000)) {
    const auto end = Clock::now() + limit;
    while (Clock::now() < end) {
      auto head = igtl::MessageHeader::New();
      head->InitPack();
      const int r = sock_->Receive(head->GetPackPointer(), head->GetPackSize());
      if (r < 0) continue;  // timeout, try again until the limit
      if (r != head->GetPackSize()) return false;
      head->Unpack();
      if (std::strcmp(head->GetDeviceType(), "STRING") != 0 || name != head->GetDeviceName()) {
        sock_->Skip(head->GetBodySizeToRead(), 1);
        continue;
      }
      auto msg = igtl::StringMessage::New();
      msg->SetMessageHeader(head);
      msg->AllocatePack();
      if (sock_->Receive(msg->GetPackBodyPointer(), msg->GetPackBodySize()) !=
          msg->GetPackBodySize())
        return false;
      if (!(msg->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) return false;  // CRC checked
      text = msg->GetString();
      return true;
    }
    return false;
  }

  // Insertion depth along z and a rotation about z, as docs/devices.md describes.
  bool send_transform(const char* name, double depth_mm, double angle_deg = 0.0) {
    igtl::Matrix4x4 m;
    igtl::IdentityMatrix(m);
    const double a = angle_deg * 3.14159265358979323846 / 180.0;
    m[0][0] = static_cast<float>(std::cos(a));
    m[0][1] = static_cast<float>(-std::sin(a));
    m[1][0] = static_cast<float>(std::sin(a));
    m[1][1] = static_cast<float>(std::cos(a));
    m[2][3] = static_cast<float>(depth_mm);
    auto msg = igtl::TransformMessage::New();
    msg->SetDeviceName(name);
    msg->SetMatrix(m);
    msg->Pack();
    return send_raw(msg->GetPackPointer(), msg->GetPackSize());
  }

  // Reads messages until a SENSOR named `name` arrives; false on timeout or a closed socket.
  bool read_sensor(const std::string& name, std::vector<double>& values,
                   std::chrono::milliseconds limit = std::chrono::milliseconds(2000)) {
    const auto end = Clock::now() + limit;
    while (Clock::now() < end) {
      auto head = igtl::MessageHeader::New();
      head->InitPack();
      const int r = sock_->Receive(head->GetPackPointer(), head->GetPackSize());
      if (r < 0) continue;  // timeout, try again until the limit
      if (r != head->GetPackSize()) return false;
      head->Unpack();
      if (std::strcmp(head->GetDeviceType(), "SENSOR") != 0 || name != head->GetDeviceName()) {
        sock_->Skip(head->GetBodySizeToRead(), 1);
        continue;
      }
      auto msg = igtl::SensorMessage::New();
      msg->SetMessageHeader(head);
      msg->AllocatePack();
      if (sock_->Receive(msg->GetPackBodyPointer(), msg->GetPackBodySize()) !=
          msg->GetPackBodySize())
        return false;
      if (!(msg->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) return false;  // CRC checked
      values.resize(msg->GetLength());
      for (unsigned int i = 0; i < msg->GetLength(); ++i) values[i] = msg->GetValue(i);
      return true;
    }
    return false;
  }

 private:
  igtl::ClientSocket::Pointer sock_;
};

}  // namespace vcsim::test

// A test suite sharing one headless EGL context (Mesa llvmpipe), skipped with the reason where
// EGL is unavailable. Derive a suite from it: `class MyGl : public test::GlSuite {};`.
#pragma once

#include <gtest/gtest.h>

#include <exception>
#include <memory>
#include <string>

#include "vcsim/render.h"

namespace vcsim::test {

class GlSuite : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    try {
      gl() = std::make_unique<HeadlessGlContext>();
    } catch (const std::exception& e) {
      why() = e.what();
    }
  }
  static void TearDownTestSuite() { gl().reset(); }
  void SetUp() override {
    if (!gl()) GTEST_SKIP() << "EGL unavailable: " << why();
  }
  static std::unique_ptr<HeadlessGlContext>& gl() {
    static std::unique_ptr<HeadlessGlContext> context;
    return context;
  }
  static std::string& why() {
    static std::string text;
    return text;
  }
};

}  // namespace vcsim::test

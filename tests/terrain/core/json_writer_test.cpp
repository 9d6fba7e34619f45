#include "libterrain/core/json_writer.h"

#include <gtest/gtest.h>

#include <limits>

namespace tinbuild {
namespace {

TEST(JsonWriter, NestedStructuresAndEscapes) {
  JsonWriter j(0);
  j.beginObject();
  j.key("a").value(1);
  j.key("s").value("q\"\\\n\x01");
  j.key("arr").beginArray().value(1.5).value(true).null().endArray();
  j.key("empty").beginObject().endObject();
  j.key("nan").value(std::numeric_limits<double>::quiet_NaN());
  j.endObject();
  EXPECT_EQ(j.str(), R"({"a":1,"s":"q\"\\\n\u0001","arr":[1.5,true,null],"empty":{},"nan":null})");
}

TEST(JsonWriter, DoublesRoundTrip) {
  JsonWriter j(0);
  j.beginArray().value(0.1).value(4500000.123456789).value(1e-300).endArray();
  EXPECT_EQ(j.str(), "[0.1,4500000.123456789,1e-300]");
}

}  // namespace
}  // namespace tinbuild

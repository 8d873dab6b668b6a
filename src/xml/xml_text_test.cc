// Malformed documents are reported at the mistake, with a column, and what pugixml alone lets
// through (a repeated attribute, `--` in a comment) is refused as xmllint refuses it.
#include <gtest/gtest.h>

#include "icars/xml/xml_text.h"

namespace icars::xml {
namespace {

std::optional<XmlProblem> load(std::string_view text) {
  pugi::xml_document doc;
  return XmlText(text).load(doc);
}

TEST(XmlText, PositionsCountLinesAndCharacters) {
  const std::string_view text = "<a>\n  <b x=\"\xc3\xa9\xc3\xa9\" y=\"1\"/>\n</a>\n";
  const XmlText xml(text);
  EXPECT_EQ(xml.position(0).line, 1u);
  EXPECT_EQ(xml.position(0).column, 1u);
  const auto y = text.find("y=");
  EXPECT_EQ(xml.position(static_cast<std::ptrdiff_t>(y)).line, 2u);
  EXPECT_EQ(xml.position(static_cast<std::ptrdiff_t>(y)).column, 13u) << "two-byte characters count once";
  pugi::xml_document doc;
  ASSERT_FALSE(xml.load(doc));
  const auto b = doc.child("a").child("b");
  EXPECT_EQ(xml.position(b).line, 2u);
  EXPECT_EQ(xml.position(b).column, 3u) << "an element is where its '<' is";
  EXPECT_EQ(xml.position(1'000'000).line, 4u) << "past the end: the end";
}

TEST(XmlText, ATagWithoutItsClosingBracketIsReportedWhereItOpens) {
  const auto problem = load("<policy>\n  <task name=\"a\">\n    <behavior type=\"Wait\"\n  </task>\n</policy>\n");
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->at.line, 3u);
  EXPECT_EQ(problem->at.column, 5u);
  EXPECT_NE(problem->message.find("the tag <behavior> is not well-formed"), std::string::npos) << problem->message;
  EXPECT_NE(problem->message.find("at line 4, column 3"), std::string::npos) << problem->message;
}

TEST(XmlText, AnUnclosedQuoteIsReportedAtItsTag) {
  const auto problem = load("<house>\n  <room name=\"a x0=\"1\"/>\n</house>\n");
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->at.line, 2u);
  EXPECT_EQ(problem->at.column, 3u);
  EXPECT_NE(problem->message.find("<room>"), std::string::npos) << problem->message;
}

TEST(XmlText, AMismatchedClosingTagNamesTheElementLeftOpen) {
  const auto problem = load("<policy>\n  <task name=\"a\">\n    <wait/>\n    <behavior>\n  </task>\n</policy>\n");
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->at.line, 5u);
  EXPECT_EQ(problem->at.column, 3u);
  EXPECT_EQ(problem->message, "malformed XML: </task> closes <behavior> opened at line 4, expected </behavior>");
}

TEST(XmlText, ADocumentThatEndsEarlyNamesTheOpenElement) {
  const auto problem = load("<policy>\n  <task name=\"a\"/>\n");
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->at.line, 3u);
  EXPECT_NE(problem->message.find("<policy>"), std::string::npos) << problem->message;
}

TEST(XmlText, ARepeatedAttributeIsMalformed) {
  const auto problem = load("<policy>\n  <task name=\"a\" name=\"b\"/>\n</policy>\n");
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->at.line, 2u);
  EXPECT_EQ(problem->at.column, 3u);
  EXPECT_EQ(problem->message, "malformed XML: <task> has attribute \"name\" twice");
}

TEST(XmlText, DoubleHyphensInACommentAreMalformed) {
  const auto problem = load("<house>\n  <!-- rooms -- and doors -->\n</house>\n");
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->at.line, 2u);
  EXPECT_EQ(problem->at.column, 3u);
  EXPECT_NE(problem->message.find("'--'"), std::string::npos);
  EXPECT_TRUE(load("<house>\n  <!-- rooms - and - doors -->\n</house>\n") == std::nullopt);
}

TEST(XmlText, CommentsAreDroppedFromAWellFormedDocument) {
  pugi::xml_document doc;
  const std::string_view text = "<!-- a --><a><!-- b --><b/><!-- c --></a>";
  ASSERT_FALSE(XmlText(text).load(doc));
  const auto a = doc.document_element();
  EXPECT_STREQ(a.name(), "a");
  EXPECT_STREQ(a.first_child().name(), "b");
  EXPECT_FALSE(a.first_child().next_sibling());
}

TEST(XmlText, OtherErrorsSayWhatTheParserFound) {
  const auto problem = load("<a>\n  <b x=1/>\n</a>\n");
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->message.rfind("malformed XML: ", 0), 0u);
  const auto empty = load("");
  ASSERT_TRUE(empty);
  EXPECT_EQ(empty->at.line, 1u);
  EXPECT_EQ(empty->message, "malformed XML: No document element found");
}

}  // namespace
}  // namespace icars::xml

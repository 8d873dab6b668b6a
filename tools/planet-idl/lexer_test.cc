// The lexer: tokens with exact locations, comments skipped, keywords told from names, and
// precise errors for bytes that cannot start a token or unterminated comments and strings.
#include "lexer.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace icars::planet::idl {
namespace {

std::vector<TokenKind> kinds(std::string_view text) {
  std::vector<TokenKind> out;
  for (const Token& t : tokenize("t.idl", text)) out.push_back(t.kind);
  return out;
}

std::string error_of(std::string_view text) {
  try {
    tokenize("t.idl", text);
  } catch (const CompileError& e) {
    return e.what();
  }
  return "no error";
}

TEST(Lexer, SplitsPunctuationNamesNumbersAndStrings) {
  using K = TokenKind;
  EXPECT_EQ(kinds("module a::b { } ( ) < > ; , : = - 42 0x1F \"x.idl\""),
            (std::vector<K>{K::keyword, K::identifier, K::scope, K::identifier, K::left_brace,
                            K::right_brace, K::left_paren, K::right_paren, K::left_angle,
                            K::right_angle, K::semicolon, K::comma, K::colon, K::equals, K::minus,
                            K::integer, K::integer, K::string, K::end_of_file}));
}

TEST(Lexer, NestedAnglesAreSeparateTokens) {
  using K = TokenKind;
  EXPECT_EQ(kinds("sequence<sequence<int>>"),
            (std::vector<K>{K::keyword, K::left_angle, K::keyword, K::left_angle, K::keyword,
                            K::right_angle, K::right_angle, K::end_of_file}));
}

TEST(Lexer, TracksLinesAndColumnsAcrossComments) {
  const auto tokens = tokenize("t.idl", "// line one\n  /* two\n three */ name\n\tx");
  ASSERT_EQ(tokens.size(), 3u);
  EXPECT_EQ(tokens[0].text, "name");
  EXPECT_EQ(tokens[0].location.line, 3u);
  EXPECT_EQ(tokens[0].location.column, 11u);
  EXPECT_EQ(tokens[1].location.line, 4u);
  EXPECT_EQ(tokens[1].location.column, 2u);
  EXPECT_EQ(tokens[2].location.to_string(), "t.idl:4:3");
}

TEST(Lexer, KeywordsAreRecognisedOnlyAsWholeWords) {
  const auto tokens = tokenize("t.idl", "int interval oneway oneway_ish idempotent idempotently");
  EXPECT_TRUE(tokens[0].is_keyword("int"));
  EXPECT_TRUE(tokens[1].is(TokenKind::identifier));
  EXPECT_TRUE(tokens[2].is_keyword("oneway"));
  EXPECT_TRUE(tokens[3].is(TokenKind::identifier));
  EXPECT_TRUE(tokens[4].is_keyword("idempotent"));
  EXPECT_TRUE(tokens[5].is(TokenKind::identifier));
}

TEST(Lexer, IntegersKeepTheirValue) {
  const auto tokens = tokenize("t.idl", "0 2147483648 0x7fffffff 18446744073709551615");
  EXPECT_EQ(tokens[0].value, 0u);
  EXPECT_EQ(tokens[1].value, 2147483648u);
  EXPECT_EQ(tokens[2].value, 0x7fffffffu);
  EXPECT_EQ(tokens[3].value, 18446744073709551615u);
}

TEST(Lexer, ReportsErrorsAtTheirPosition) {
  EXPECT_EQ(error_of("a /* never closed"),
            "t.idl:1:3: error: unterminated comment, expected '*/' before the end of the file");
  EXPECT_EQ(error_of("include \"x.idl;\n"),
            "t.idl:1:9: error: unterminated string, expected '\"' before the end of the line");
  EXPECT_EQ(error_of("a\n  $"),
            "t.idl:2:3: error: unexpected character '$', expected an identifier, a number, a "
            "string, a comment or one of { } ( ) < > ; , : = -");
  EXPECT_EQ(error_of("\xff\xfe"),
            "t.idl:1:1: error: unexpected character '\\xff', expected an "
            "identifier, a number, a string, a comment or one of { } ( ) < > "
            "; , : = -");
  EXPECT_EQ(
      error_of("x = 18446744073709551616;"),
      "t.idl:1:5: error: integer literal is too large, expected a value that fits in 64 bits");
  EXPECT_EQ(error_of("12abc"),
            "t.idl:1:3: error: unexpected 'a' in a number, expected a digit or a separator");
  EXPECT_EQ(error_of("0x;"), "t.idl:1:3: error: '0x' without digits, expected a hexadecimal digit");
  EXPECT_EQ(error_of(std::string_view("a\0b", 3)).substr(0, 38),
            "t.idl:1:2: error: unexpected character");
}

TEST(Lexer, DescribesTokensForMessages) {
  const auto tokens = tokenize("t.idl", "name \"file\" {");
  EXPECT_EQ(describe(tokens[0]), "'name'");
  EXPECT_EQ(describe(tokens[1]), "string \"file\"");
  EXPECT_EQ(describe(tokens[2]), "'{'");
  EXPECT_EQ(describe(tokens[3]), "end of file");
  EXPECT_EQ(describe(TokenKind::semicolon), "';'");
}

}  // namespace
}  // namespace icars::planet::idl

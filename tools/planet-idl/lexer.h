// planet-idl lexer: turns the bytes of one IDL file into tokens.
//
// Whitespace and comments (`// ...` to the end of the line, `/* ... */`, not nested) separate
// tokens and are dropped. Keywords are recognised here, so the parser never confuses `int` with
// a name. Any byte that cannot start a token, an unterminated comment or string, or an integer
// too large for 64 bits is a CompileError at its exact position.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "diagnostic.h"

namespace icars::planet::idl {

enum class TokenKind : std::uint8_t {
  end_of_file,
  identifier,
  keyword,
  integer,  // decimal or 0x hexadecimal, without sign
  string,   // "..." on one line; `text` excludes the quotes
  left_brace,
  right_brace,
  left_paren,
  right_paren,
  left_angle,
  right_angle,
  semicolon,
  comma,
  colon,
  scope,  // ::
  equals,
  minus,
};

struct Token {
  TokenKind kind = TokenKind::end_of_file;
  std::string_view text;  // points into the source text
  SourceLocation location;
  std::uint64_t value = 0;  // for integers

  bool is(TokenKind k) const { return kind == k; }
  bool is_keyword(std::string_view word) const {
    return kind == TokenKind::keyword && text == word;
  }
};

// The IDL's reserved words; none of them can name anything.
bool is_idl_keyword(std::string_view word);

// How a token is named in an error message: 'name', '{', "end of file".
std::string describe(const Token& token);
// How a token kind is named when it was expected: "an identifier", "'{'".
std::string describe(TokenKind kind);

// Splits `text` into tokens, ending with one end_of_file token. `file` is only used for
// locations and must outlive the tokens; so must `text`.
std::vector<Token> tokenize(std::string_view file, std::string_view text);

}  // namespace icars::planet::idl

#include "lexer.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <limits>

namespace icars::planet::idl {

namespace {

constexpr std::array kKeywords = {
    std::string_view("binary"),    std::string_view("bool"),      std::string_view("byte"),
    std::string_view("double"),    std::string_view("enum"),      std::string_view("event"),
    std::string_view("exception"), std::string_view("float"),     std::string_view("idempotent"),
    std::string_view("include"),   std::string_view("int"),       std::string_view("interface"),
    std::string_view("long"),
    std::string_view("module"),    std::string_view("oneway"),    std::string_view("raises"),
    std::string_view("sequence"),  std::string_view("short"),     std::string_view("stream"),
    std::string_view("string"),    std::string_view("valued"),    std::string_view("void"),
};

bool is_letter(char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_'; }
bool is_digit(char c) { return c >= '0' && c <= '9'; }
bool is_hex_digit(char c) {
  return is_digit(c) || (c >= 'a' && c <= 'f') || (c >= 'A' && c <= 'F');
}
unsigned digit_value(char c) {
  if (is_digit(c)) return static_cast<unsigned>(c - '0');
  if (c >= 'a' && c <= 'f') return static_cast<unsigned>(c - 'a' + 10);
  return static_cast<unsigned>(c - 'A' + 10);
}

constexpr std::string_view kTokenStart =
    "an identifier, a number, a string, a comment or one of { } ( ) < > ; , : = -";

class Lexer {
 public:
  Lexer(std::string_view file, std::string_view text) : file_(file), text_(text) {}

  std::vector<Token> run() {
    std::vector<Token> tokens;
    for (;;) {
      skip_space_and_comments();
      tokens.push_back(next());
      if (tokens.back().is(TokenKind::end_of_file)) return tokens;
    }
  }

 private:
  SourceLocation here() const { return {file_, line_, column_}; }
  bool at_end() const { return pos_ >= text_.size(); }
  char peek(std::size_t ahead = 0) const {
    return pos_ + ahead < text_.size() ? text_[pos_ + ahead] : '\0';
  }
  void advance() {
    if (text_[pos_] == '\n') {
      ++line_;
      column_ = 1;
    } else {
      ++column_;
    }
    ++pos_;
  }

  void skip_space_and_comments() {
    while (!at_end()) {
      const char c = peek();
      if (c == ' ' || c == '\t' || c == '\r' || c == '\n') {
        advance();
      } else if (c == '/' && peek(1) == '/') {
        while (!at_end() && peek() != '\n') advance();
      } else if (c == '/' && peek(1) == '*') {
        skip_block_comment();
      } else {
        return;
      }
    }
  }

  void skip_block_comment() {
    const SourceLocation start = here();
    advance();
    advance();
    while (!(peek() == '*' && peek(1) == '/')) {
      if (at_end())
        throw CompileError(start, "unterminated comment", "'*/' before the end of the file");
      advance();
    }
    advance();
    advance();
  }

  Token make(TokenKind kind, std::size_t start, SourceLocation where) const {
    return Token{kind, text_.substr(start, pos_ - start), where, 0};
  }

  Token next() {
    const SourceLocation where = here();
    const std::size_t start = pos_;
    if (at_end()) return Token{TokenKind::end_of_file, {}, where, 0};
    const char c = peek();
    if (is_letter(c)) return word(start, where);
    if (is_digit(c)) return number(start, where);
    if (c == '"') return string(where);
    if (c == ':' && peek(1) == ':') {
      advance();
      advance();
      return make(TokenKind::scope, start, where);
    }
    const TokenKind kind = punctuation(c, where);
    advance();
    return make(kind, start, where);
  }

  TokenKind punctuation(char c, const SourceLocation& where) const {
    switch (c) {
      case '{':
        return TokenKind::left_brace;
      case '}':
        return TokenKind::right_brace;
      case '(':
        return TokenKind::left_paren;
      case ')':
        return TokenKind::right_paren;
      case '<':
        return TokenKind::left_angle;
      case '>':
        return TokenKind::right_angle;
      case ';':
        return TokenKind::semicolon;
      case ',':
        return TokenKind::comma;
      case ':':
        return TokenKind::colon;
      case '=':
        return TokenKind::equals;
      case '-':
        return TokenKind::minus;
      default:
        throw CompileError(where,
                           fmt::format("unexpected character {}", quote(std::string_view(&c, 1))),
                           std::string(kTokenStart));
    }
  }

  Token word(std::size_t start, SourceLocation where) {
    while (!at_end() && (is_letter(peek()) || is_digit(peek()))) advance();
    Token t = make(TokenKind::identifier, start, where);
    if (is_idl_keyword(t.text)) t.kind = TokenKind::keyword;
    return t;
  }

  Token number(std::size_t start, SourceLocation where) {
    const bool hex = peek() == '0' && (peek(1) == 'x' || peek(1) == 'X');
    const unsigned base = hex ? 16 : 10;
    if (hex) {
      advance();
      advance();
      if (!is_hex_digit(peek()))
        throw CompileError(here(), "'0x' without digits", "a hexadecimal digit");
    }
    std::uint64_t value = 0;
    while (hex ? is_hex_digit(peek()) : is_digit(peek())) {
      const unsigned d = digit_value(peek());
      if (value > (std::numeric_limits<std::uint64_t>::max() - d) / base) {
        throw CompileError(where, "integer literal is too large", "a value that fits in 64 bits");
      }
      value = value * base + d;
      advance();
    }
    if (is_letter(peek())) {
      throw CompileError(
          here(),
          fmt::format("unexpected {} in a number", quote(std::string_view(&text_[pos_], 1))),
          "a digit or a separator");
    }
    Token t = make(TokenKind::integer, start, where);
    t.value = value;
    return t;
  }

  Token string(SourceLocation where) {
    advance();
    const std::size_t start = pos_;
    while (peek() != '"') {
      if (at_end() || peek() == '\n') {
        throw CompileError(where, "unterminated string", "'\"' before the end of the line");
      }
      advance();
    }
    Token t{TokenKind::string, text_.substr(start, pos_ - start), where, 0};
    advance();
    return t;
  }

  std::string_view file_;
  std::string_view text_;
  std::size_t pos_ = 0;
  std::uint32_t line_ = 1;
  std::uint32_t column_ = 1;
};

}  // namespace

bool is_idl_keyword(std::string_view word) {
  return std::find(kKeywords.begin(), kKeywords.end(), word) != kKeywords.end();
}

std::string describe(const Token& token) {
  switch (token.kind) {
    case TokenKind::end_of_file:
      return "end of file";
    case TokenKind::string:
      return fmt::format("string \"{}\"", token.text);
    default:
      return quote(token.text);
  }
}

std::string describe(TokenKind kind) {
  switch (kind) {
    case TokenKind::end_of_file:
      return "end of file";
    case TokenKind::identifier:
      return "an identifier";
    case TokenKind::keyword:
      return "a keyword";
    case TokenKind::integer:
      return "an integer";
    case TokenKind::string:
      return "a string";
    case TokenKind::left_brace:
      return "'{'";
    case TokenKind::right_brace:
      return "'}'";
    case TokenKind::left_paren:
      return "'('";
    case TokenKind::right_paren:
      return "')'";
    case TokenKind::left_angle:
      return "'<'";
    case TokenKind::right_angle:
      return "'>'";
    case TokenKind::semicolon:
      return "';'";
    case TokenKind::comma:
      return "','";
    case TokenKind::colon:
      return "':'";
    case TokenKind::scope:
      return "'::'";
    case TokenKind::equals:
      return "'='";
    case TokenKind::minus:
      return "'-'";
  }
  return "a token";
}

std::vector<Token> tokenize(std::string_view file, std::string_view text) {
  return Lexer(file, text).run();
}

}  // namespace icars::planet::idl

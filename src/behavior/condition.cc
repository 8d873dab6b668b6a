#include "icars/behavior/condition.h"

#include <fmt/format.h>

#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <optional>
#include <set>
#include <system_error>
#include <utility>

namespace icars::behavior {

namespace {

enum class NodeKind { literal, name, negation, all, any, compare, call };
enum class CompareOp { eq, ne, lt, le, gt, ge };
enum class Function { between, contains, exists, lower, number, starts_with };

struct ConditionNode {
  NodeKind kind = NodeKind::literal;
  ConditionValue literal;  // literal
  std::string name;        // name; the argument of exists
  CompareOp op = CompareOp::eq;
  Function function = Function::between;
  // Operands. and/or are n-ary, so a long chain stays one level deep (no deep recursion when
  // evaluating or destroying it).
  std::vector<std::unique_ptr<const ConditionNode>> children;
};

}  // namespace

namespace detail {

// What copies of a Condition share; immutable once parsed.
struct ConditionProgram {
  std::string text;
  std::unique_ptr<const ConditionNode> root;
  std::vector<std::string> identifiers;
};

}  // namespace detail

namespace {

using NodePtr = std::unique_ptr<const ConditionNode>;

constexpr int kMaxDepth = 64;

struct FunctionInfo {
  std::string_view name;
  Function function;
  std::size_t arity;
  std::string_view parameters;
};

// Sorted by name: the order of the "known:" list in errors.
constexpr std::array<FunctionInfo, 6> kFunctions{{
    {"between", Function::between, 3, "x, lo, hi"},
    {"contains", Function::contains, 2, "s, sub"},
    {"exists", Function::exists, 1, "name"},
    {"lower", Function::lower, 1, "s"},
    {"number", Function::number, 1, "s"},
    {"starts_with", Function::starts_with, 2, "s, prefix"},
}};

bool is_digit(char c) { return c >= '0' && c <= '9'; }
bool is_name_start(char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_'; }
bool is_name_char(char c) { return is_name_start(c) || is_digit(c) || c == '.'; }
bool is_blank(char c) {
  return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\f' || c == '\v';
}
char to_lower(char c) { return c >= 'A' && c <= 'Z' ? static_cast<char>(c - 'A' + 'a') : c; }
std::string lowered(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = to_lower(c);
  return out;
}

// 1-based column of byte offset `pos`, counting UTF-8 code points (continuation bytes are not
// columns of their own).
std::size_t column_of(std::string_view text, std::size_t pos) {
  std::size_t column = 1;
  for (std::size_t i = 0; i < pos && i < text.size(); ++i) {
    if ((static_cast<unsigned char>(text[i]) & 0xC0) != 0x80) ++column;
  }
  return column;
}

// Source text for an error message: printable ASCII as is, other bytes as \xNN, long text cut.
std::string printable(std::string_view s) {
  constexpr std::size_t kMaxShown = 24;
  std::string out;
  for (std::size_t i = 0; i < s.size() && i < kMaxShown; ++i) {
    const auto b = static_cast<unsigned char>(s[i]);
    if (b >= 0x20 && b < 0x7F) {
      out += s[i];
    } else {
      out += fmt::format("\\x{:02X}", b);
    }
  }
  if (s.size() > kMaxShown) out += "...";
  return out;
}

// Source text in single quotes, for text that is not a quoted string literal itself.
std::string quoted(std::string_view s) { return fmt::format("'{}'", printable(s)); }

enum class Tok {
  end,
  number,
  string,
  name,
  kw_and,
  kw_or,
  kw_not,
  kw_true,
  kw_false,
  lparen,
  rparen,
  comma,
  minus,
  compare
};

struct Token {
  Tok kind = Tok::end;
  std::size_t pos = 0;     // byte offset in the text
  std::size_t length = 0;  // bytes of source text
  double number = 0;
  bool time_of_day = false;  // a number written as HH:MM[:SS]
  std::string text;          // a string literal's value, or a name
  CompareOp op = CompareOp::eq;
};

// Recursive descent over tokens lexed one at a time, so errors come out left to right.
class Parser {
 public:
  explicit Parser(std::string_view text) : text_(text) { advance(); }

  NodePtr parse_all() {
    NodePtr root = parse_or();
    if (tok_.kind == Tok::compare) fail_chained();
    if (tok_.kind != Tok::end) {
      fail(tok_.pos, "expected 'and', 'or' or end of condition, found " + found());
    }
    return root;
  }

  std::vector<std::string> take_identifiers() { return std::move(identifiers_); }

 private:
  // One nesting level (parenthesis, call, not); fails beyond kMaxDepth.
  class Nested {
   public:
    Nested(Parser& parser, std::size_t pos) : parser_(parser) {
      if (++parser_.depth_ > kMaxDepth) {
        parser_.fail(pos, fmt::format("condition nested too deeply (more than {} levels of "
                                      "parentheses, function calls and 'not')",
                                      kMaxDepth));
      }
    }
    ~Nested() { --parser_.depth_; }
    Nested(const Nested&) = delete;
    Nested& operator=(const Nested&) = delete;

   private:
    Parser& parser_;
  };

  [[noreturn]] void fail(std::size_t pos, const std::string& message) const {
    throw ConditionError(message, column_of(text_, pos));
  }
  [[noreturn]] void fail_chained() const {
    fail(tok_.pos, "comparisons do not chain: write 'a < b and b < c' instead of 'a < b < c'");
  }

  std::string found() const {
    if (tok_.kind == Tok::end) return "end of condition";
    const std::string_view source = text_.substr(tok_.pos, tok_.length);
    // A string literal's source text has its quotes already.
    if (tok_.kind == Tok::string) return "string " + printable(source);
    return quoted(source);
  }

  static NodePtr make_literal(ConditionValue v) {
    auto node = std::make_unique<ConditionNode>();
    node->literal = std::move(v);
    return node;
  }

  void note_identifier(const std::string& name) {
    if (seen_.insert(name).second) identifiers_.push_back(name);
  }

  NodePtr parse_or() { return parse_chain(Tok::kw_or, NodeKind::any); }
  NodePtr parse_and() { return parse_chain(Tok::kw_and, NodeKind::all); }

  // operand (op operand)*, as one n-ary node when there is more than one operand.
  NodePtr parse_chain(Tok op, NodeKind kind) {
    NodePtr first = kind == NodeKind::any ? parse_and() : parse_not();
    if (tok_.kind != op) return first;
    auto node = std::make_unique<ConditionNode>();
    node->kind = kind;
    node->children.push_back(std::move(first));
    while (tok_.kind == op) {
      advance();
      node->children.push_back(kind == NodeKind::any ? parse_and() : parse_not());
    }
    return node;
  }

  NodePtr parse_not() {
    if (tok_.kind != Tok::kw_not) return parse_comparison();
    const Nested nested(*this, tok_.pos);
    advance();
    auto node = std::make_unique<ConditionNode>();
    node->kind = NodeKind::negation;
    node->children.push_back(parse_not());
    return node;
  }

  NodePtr parse_comparison() {
    NodePtr lhs = parse_primary();
    if (tok_.kind != Tok::compare) return lhs;
    auto node = std::make_unique<ConditionNode>();
    node->kind = NodeKind::compare;
    node->op = tok_.op;
    advance();
    node->children.push_back(std::move(lhs));
    node->children.push_back(parse_primary());
    if (tok_.kind == Tok::compare) fail_chained();
    return node;
  }

  NodePtr parse_primary() {
    switch (tok_.kind) {
      case Tok::number: {
        auto node = make_literal(tok_.number);
        advance();
        return node;
      }
      case Tok::minus: {
        advance();
        if (tok_.kind != Tok::number || tok_.time_of_day) {
          fail(tok_.pos, "expected a number or duration after '-', found " + found());
        }
        auto node = make_literal(-tok_.number);
        advance();
        return node;
      }
      case Tok::string: {
        auto node = make_literal(std::move(tok_.text));
        advance();
        return node;
      }
      case Tok::kw_true:
      case Tok::kw_false: {
        auto node = make_literal(tok_.kind == Tok::kw_true);
        advance();
        return node;
      }
      case Tok::name: {
        const std::size_t pos = tok_.pos;
        std::string name = std::move(tok_.text);
        advance();
        if (tok_.kind == Tok::lparen) return parse_call(pos, name);
        note_identifier(name);
        auto node = std::make_unique<ConditionNode>();
        node->kind = NodeKind::name;
        node->name = std::move(name);
        return node;
      }
      case Tok::lparen: {
        const std::size_t open = tok_.pos;
        const Nested nested(*this, open);
        advance();
        NodePtr inner = parse_or();
        if (tok_.kind == Tok::compare) fail_chained();
        if (tok_.kind != Tok::rparen) {
          fail(tok_.pos, fmt::format("expected ')' to close the '(' at column {}, found {}",
                                     column_of(text_, open), found()));
        }
        advance();
        return inner;
      }
      default:
        fail(tok_.pos, "expected an expression, found " + found());
    }
  }

  // At the '(' after a function name.
  NodePtr parse_call(std::size_t name_pos, const std::string& name) {
    const FunctionInfo* info = nullptr;
    for (const auto& f : kFunctions) {
      if (f.name == name) info = &f;
    }
    if (info == nullptr) {
      fail(name_pos, fmt::format("unknown function {} (known: between, contains, exists, lower, "
                                 "number, starts_with)",
                                 quoted(name)));
    }
    const Nested nested(*this, tok_.pos);
    advance();
    auto node = std::make_unique<ConditionNode>();
    node->kind = NodeKind::call;
    node->function = info->function;
    std::size_t count = 0;
    if (info->function == Function::exists) {
      if (tok_.kind != Tok::name) {
        fail(tok_.pos, "exists takes a bare name, e.g. exists(battery), found " + found());
      }
      node->name = std::move(tok_.text);
      note_identifier(node->name);
      advance();
      count = 1;
    } else if (tok_.kind != Tok::rparen) {
      for (;;) {
        node->children.push_back(parse_or());
        ++count;
        if (tok_.kind == Tok::comma) {
          advance();
          continue;
        }
        if (tok_.kind == Tok::rparen) break;
        if (tok_.kind == Tok::compare) fail_chained();
        fail(tok_.pos, fmt::format("expected {} after the arguments of {}, found {}",
                                   count < info->arity ? "',' or ')'" : "')'", name, found()));
      }
    }
    if (tok_.kind != Tok::rparen) {
      fail(tok_.pos, fmt::format("expected ')' after the argument of {}, found {}", name, found()));
    }
    if (count != info->arity) {
      fail(name_pos, fmt::format("{} takes {} argument{} ({}), found {}", name, info->arity,
                                 info->arity == 1 ? "" : "s", info->parameters, count));
    }
    advance();
    return node;
  }

  // --- Lexer ---

  void advance() {
    while (pos_ < text_.size() && is_blank(text_[pos_])) ++pos_;
    tok_ = Token{};
    tok_.pos = pos_;
    if (pos_ >= text_.size()) {
      tok_.kind = Tok::end;
      return;
    }
    const char c = text_[pos_];
    const char next = pos_ + 1 < text_.size() ? text_[pos_ + 1] : '\0';
    const auto single = [&](Tok kind, std::size_t length = 1) {
      tok_.kind = kind;
      tok_.length = length;
      pos_ += length;
    };
    const auto compare = [&](CompareOp op, std::size_t length) {
      tok_.op = op;
      single(Tok::compare, length);
    };
    if (is_digit(c)) return lex_number();
    if (is_name_start(c)) return lex_name();
    if (c == '\'' || c == '"') return lex_string();
    switch (c) {
      case '(':
        return single(Tok::lparen);
      case ')':
        return single(Tok::rparen);
      case ',':
        return single(Tok::comma);
      case '-':
        return single(Tok::minus);
      case '<':
        return next == '=' ? compare(CompareOp::le, 2) : compare(CompareOp::lt, 1);
      case '>':
        return next == '=' ? compare(CompareOp::ge, 2) : compare(CompareOp::gt, 1);
      case '!':
        return next == '=' ? compare(CompareOp::ne, 2) : single(Tok::kw_not);
      case '=':
        if (next == '=') return compare(CompareOp::eq, 2);
        fail(pos_, "unexpected '=': compare with '=='");
      case '&':
        if (next == '&') return single(Tok::kw_and, 2);
        fail(pos_, "unexpected '&': write '&&' or 'and'");
      case '|':
        if (next == '|') return single(Tok::kw_or, 2);
        fail(pos_, "unexpected '|': write '||' or 'or'");
      default:
        fail(pos_, "unexpected character " + quoted(text_.substr(pos_, 1)));
    }
  }

  void lex_name() {
    const std::size_t start = pos_;
    while (pos_ < text_.size() && is_name_char(text_[pos_])) ++pos_;
    const std::string_view word = text_.substr(start, pos_ - start);
    tok_.length = word.size();
    if (word == "and") {
      tok_.kind = Tok::kw_and;
    } else if (word == "or") {
      tok_.kind = Tok::kw_or;
    } else if (word == "not") {
      tok_.kind = Tok::kw_not;
    } else if (word == "true") {
      tok_.kind = Tok::kw_true;
    } else if (word == "false") {
      tok_.kind = Tok::kw_false;
    } else {
      tok_.kind = Tok::name;
      tok_.text = std::string(word);
    }
  }

  // Numbers 2, 2.5; durations 500ms 30s 5min 2h; times of day 21:30, 21:30:15.
  void lex_number() {
    const std::size_t start = pos_;
    while (pos_ < text_.size() && is_digit(text_[pos_])) ++pos_;
    tok_.kind = Tok::number;
    if (pos_ < text_.size() && text_[pos_] == ':') {
      while (pos_ < text_.size() && (is_digit(text_[pos_]) || text_[pos_] == ':')) ++pos_;
      while (pos_ < text_.size() && is_name_char(text_[pos_])) ++pos_;  // "07:00pm" is one token
      const std::string_view word = text_.substr(start, pos_ - start);
      const auto time = parse_time_of_day(word);
      if (!time) {
        fail(start, quoted(word) +
                        " is not a time of day (expected HH:MM or HH:MM:SS, hours "
                        "00-23, minutes and seconds 00-59)");
      }
      tok_.length = word.size();
      tok_.number = static_cast<double>(time->count());
      tok_.time_of_day = true;
      return;
    }
    if (pos_ + 1 < text_.size() && text_[pos_] == '.' && is_digit(text_[pos_ + 1])) {
      ++pos_;
      while (pos_ < text_.size() && is_digit(text_[pos_])) ++pos_;
    }
    const std::string_view digits = text_.substr(start, pos_ - start);
    const std::size_t unit_start = pos_;
    while (pos_ < text_.size() && is_name_char(text_[pos_])) ++pos_;
    const std::string_view unit = text_.substr(unit_start, pos_ - unit_start);
    const std::string_view word = text_.substr(start, pos_ - start);
    tok_.length = word.size();
    if (!unit.empty() && unit.front() == '.') fail(start, "malformed number " + quoted(word));
    double value = 0;
    const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), value);
    if (ec != std::errc{} || end != digits.data() + digits.size()) {
      fail(start, "number " + quoted(digits) + " is out of range");
    }
    double factor = 1;
    if (unit.empty() || unit == "ms") {
      factor = 1;
    } else if (unit == "s") {
      factor = 1000;
    } else if (unit == "min") {
      factor = 60'000;
    } else if (unit == "h") {
      factor = 3'600'000;
    } else {
      fail(unit_start,
           fmt::format("unknown unit {} after {} (known: ms, s, min, h)", quoted(unit), digits));
    }
    tok_.number = value * factor;
    if (!std::isfinite(tok_.number)) fail(start, "duration " + quoted(word) + " is out of range");
  }

  void lex_string() {
    const std::size_t start = pos_;
    const char quote = text_[pos_++];
    tok_.kind = Tok::string;
    for (;;) {
      if (pos_ >= text_.size()) {
        fail(start, fmt::format("unterminated string: no closing {} for this quote", quote));
      }
      const char c = text_[pos_];
      if (c == quote) {
        ++pos_;
        break;
      }
      if (c == '\\') {
        if (pos_ + 1 >= text_.size()) {
          fail(start, fmt::format("unterminated string: no closing {} for this quote", quote));
        }
        const char escaped = text_[pos_ + 1];
        if (escaped != '\\' && escaped != '\'' && escaped != '"') {
          fail(pos_, "unknown escape " + quoted(text_.substr(pos_, 2)) +
                         " in a string (known: \\\\, \\', \\\")");
        }
        tok_.text += escaped;
        pos_ += 2;
        continue;
      }
      tok_.text += c;
      ++pos_;
    }
    tok_.length = pos_ - start;
  }

  std::string_view text_;
  std::size_t pos_ = 0;  // next byte to lex
  Token tok_;            // the current token
  int depth_ = 0;
  std::set<std::string, std::less<>> seen_;
  std::vector<std::string> identifiers_;
};

// --- Evaluation ---

bool truthy(const ConditionValue& v) {
  if (const auto* b = std::get_if<bool>(&v)) return *b;
  if (const auto* d = std::get_if<double>(&v)) return *d != 0;
  if (const auto* s = std::get_if<std::string>(&v)) return !s->empty();
  return false;
}

template <class T>
std::optional<double> number_of(const planet::Value& v) {
  if (!v.is<T>()) return std::nullopt;
  return static_cast<double>(v.as<T>());
}

ConditionValue property_value(const planet::Value& v) {
  if (v.is<bool>()) return v.as<bool>();
  if (v.is<std::string>()) return v.as<std::string>();
  for (const auto& n :
       {number_of<std::uint8_t>(v), number_of<std::int16_t>(v), number_of<std::int32_t>(v),
        number_of<std::int64_t>(v), number_of<float>(v), number_of<double>(v)}) {
    if (n) return *n;
  }
  return {};
}

ConditionValue resolve(std::string_view name, const planet::Event& event,
                       const ConditionScope& scope) {
  const auto day_ms = kDay.count();
  if (name == "event") return event.type();
  if (name == "time") {
    return static_cast<double>(((scope.now.count() % day_ms) + day_ms) % day_ms);
  }
  if (name == "day") {
    const auto ms = scope.now.count();
    const auto day = ms / day_ms - (ms % day_ms < 0 ? 1 : 0);  // floor: before day 0 is day -1
    return static_cast<double>(day);
  }
  if (const auto it = scope.variables.find(name); it != scope.variables.end()) return it->second;
  if (event.has(name)) return property_value(event.value(name));
  return {};
}

bool compare(CompareOp op, const ConditionValue& a, const ConditionValue& b) {
  if (a.index() != b.index() || std::holds_alternative<std::monostate>(a)) {
    return op == CompareOp::ne;
  }
  if (std::holds_alternative<bool>(a) && op != CompareOp::eq && op != CompareOp::ne) {
    return false;
  }
  switch (op) {
    case CompareOp::eq:
      return a == b;
    case CompareOp::ne:
      return a != b;
    case CompareOp::lt:
      return a < b;
    case CompareOp::le:
      return a <= b;
    case CompareOp::gt:
      return a > b;
    case CompareOp::ge:
      return a >= b;
  }
  return false;
}

// A whole string as a finite number ("  2.5 " yes; "", "2x", "nan", "inf" no).
ConditionValue parse_number(std::string_view s) {
  while (!s.empty() && is_blank(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_blank(s.back())) s.remove_suffix(1);
  if (s.size() > 1 && s.front() == '+' && s[1] != '-') s.remove_prefix(1);
  double value = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
  if (s.empty() || ec != std::errc{} || end != s.data() + s.size() || !std::isfinite(value)) {
    return {};
  }
  return value;
}

ConditionValue evaluate_node(const ConditionNode& node, const planet::Event& event,
                             const ConditionScope& scope);

ConditionValue call(const ConditionNode& node, const planet::Event& event,
                    const ConditionScope& scope) {
  if (node.function == Function::exists) {
    return !std::holds_alternative<std::monostate>(resolve(node.name, event, scope));
  }
  std::vector<ConditionValue> args;
  args.reserve(node.children.size());
  for (const auto& child : node.children) args.push_back(evaluate_node(*child, event, scope));
  switch (node.function) {
    case Function::between: {
      const auto* x = std::get_if<double>(&args[0]);
      const auto* lo = std::get_if<double>(&args[1]);
      const auto* hi = std::get_if<double>(&args[2]);
      if (x == nullptr || lo == nullptr || hi == nullptr) return {};
      if (*lo <= *hi) return *lo <= *x && *x < *hi;
      return *lo <= *x || *x < *hi;  // wraps, e.g. 21:00 to 06:00
    }
    case Function::contains:
    case Function::starts_with: {
      const auto* s = std::get_if<std::string>(&args[0]);
      const auto* part = std::get_if<std::string>(&args[1]);
      if (s == nullptr || part == nullptr) return {};
      const std::string hay = lowered(*s);
      const std::string needle = lowered(*part);
      if (node.function == Function::contains) return hay.find(needle) != std::string::npos;
      return hay.starts_with(needle);
    }
    case Function::lower: {
      const auto* s = std::get_if<std::string>(&args[0]);
      if (s == nullptr) return {};
      return lowered(*s);
    }
    case Function::number: {
      if (std::holds_alternative<double>(args[0])) return args[0];
      const auto* s = std::get_if<std::string>(&args[0]);
      if (s == nullptr) return {};
      return parse_number(*s);
    }
    case Function::exists:
      break;
  }
  return {};
}

ConditionValue evaluate_node(const ConditionNode& node, const planet::Event& event,
                             const ConditionScope& scope) {
  switch (node.kind) {
    case NodeKind::literal:
      return node.literal;
    case NodeKind::name:
      return resolve(node.name, event, scope);
    case NodeKind::negation:
      return !truthy(evaluate_node(*node.children[0], event, scope));
    case NodeKind::all:
      for (const auto& child : node.children) {
        if (!truthy(evaluate_node(*child, event, scope))) return false;
      }
      return true;
    case NodeKind::any:
      for (const auto& child : node.children) {
        if (truthy(evaluate_node(*child, event, scope))) return true;
      }
      return false;
    case NodeKind::compare:
      return compare(node.op, evaluate_node(*node.children[0], event, scope),
                     evaluate_node(*node.children[1], event, scope));
    case NodeKind::call:
      return call(node, event, scope);
  }
  return {};
}

}  // namespace

ConditionError::ConditionError(std::string message, std::size_t column)
    : std::runtime_error(fmt::format("column {}: {}", column, message)), column_(column) {}

Condition::Condition() = default;

Condition::Condition(std::shared_ptr<const detail::ConditionProgram> program)
    : program_(std::move(program)) {}

Condition Condition::parse(std::string_view text) {
  bool blank = true;
  for (const char c : text) blank = blank && is_blank(c);
  if (blank) return Condition();
  Parser parser(text);
  auto program = std::make_shared<detail::ConditionProgram>();
  program->root = parser.parse_all();
  program->text = std::string(text);
  program->identifiers = parser.take_identifiers();
  return Condition(std::move(program));
}

bool Condition::evaluate(const planet::Event& event, const ConditionScope& scope) const {
  return truthy(value(event, scope));
}

ConditionValue Condition::value(const planet::Event& event, const ConditionScope& scope) const {
  if (program_ == nullptr) return true;
  return evaluate_node(*program_->root, event, scope);
}

const std::string& Condition::text() const {
  static const std::string kEmpty;
  return program_ == nullptr ? kEmpty : program_->text;
}

std::vector<std::string> Condition::identifiers() const {
  if (program_ == nullptr) return {};
  return program_->identifiers;
}

namespace {

void collect_compared_strings(const ConditionNode& node,
                              std::vector<std::pair<std::string, std::string>>& out) {
  if (node.kind == NodeKind::compare && (node.op == CompareOp::eq || node.op == CompareOp::ne) &&
      node.children.size() == 2) {
    const auto& a = *node.children[0];
    const auto& b = *node.children[1];
    const auto* name = a.kind == NodeKind::name ? &a : b.kind == NodeKind::name ? &b : nullptr;
    const auto* literal = a.kind == NodeKind::literal ? &a : b.kind == NodeKind::literal ? &b : nullptr;
    if (name != nullptr && literal != nullptr && std::holds_alternative<std::string>(literal->literal)) {
      out.emplace_back(name->name, std::get<std::string>(literal->literal));
    }
  }
  for (const auto& child : node.children) collect_compared_strings(*child, out);  // at most 64 deep
}

}  // namespace

std::vector<std::pair<std::string, std::string>> Condition::compared_strings() const {
  std::vector<std::pair<std::string, std::string>> out;
  if (program_ != nullptr) collect_compared_strings(*program_->root, out);
  return out;
}

}  // namespace icars::behavior

#include "toml.hpp"

#include <sys/stat.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>

#include "files.hpp"

namespace iwr::app {

const TomlValue* TomlValue::find(const std::string& key) const {
    for (const auto& e : entries)
        if (e.first == key) return &e.second;
    return nullptr;
}

TomlValue* TomlValue::find(const std::string& key) {
    for (auto& e : entries)
        if (e.first == key) return &e.second;
    return nullptr;
}

const char* TomlValue::kind_name(Kind k) {
    switch (k) {
        case Kind::Number: return "a number";
        case Kind::String: return "a string";
        case Kind::Array: return "an array";
        case Kind::Table: return "a table";
        case Kind::TableArray: return "an array of tables";
    }
    return "?";
}

std::string read_file(const std::string& path, const char* kind) {
    struct stat st {};
    if (::stat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode))
        throw InputError(path + ": is a folder, not " + kind);
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        const int err = errno;
        if (err == ENOENT) throw InputError(path + ": no such file");
        throw InputError(path + ": cannot be opened (" + std::strerror(err) + ")");
    }
    std::ostringstream ss;
    ss << in.rdbuf();
    if (in.bad()) throw InputError(path + ": read error");
    return ss.str();
}

namespace {

// A TOML 1.0 reader (what Python's tomllib reads, and the iwr robot files need): tables, arrays of
// tables, dotted keys, inline tables, numbers, strings of the four kinds, arrays, comments.
// Booleans and dates are refused here: no key of an iwr file takes one, and tomllib's reader of
// the robot refuses them too, a step later.
class Parser {
public:
    Parser(const std::string& text, const std::string& file) : s_(text), file_(file) {}

    TomlValue parse() {
        TomlValue root;
        root.kind = TomlValue::Kind::Table;
        root.defined = true;
        root.line = 1;
        TomlValue* current = &root;
        for (;;) {
            skip_blank_lines();
            if (eof()) break;
            if (peek() == '[') {
                ++section_;
                current = header(root);
            } else {
                key_value(*current, true);
            }
            end_of_line();
        }
        return root;
    }

private:
    // "line L, column C: what", at the current position (the column in characters).
    [[noreturn]] void fail(const std::string& what) const {
        std::size_t column = 1;
        for (std::size_t k = line_start_; k < i_ && k < s_.size(); ++k)
            column += (static_cast<unsigned char>(s_[k]) & 0xC0) != 0x80;
        throw InputError(file_ + ": line " + std::to_string(line_) + ", column " + std::to_string(column) +
                         ": " + what);
    }
    [[noreturn]] void fail_at(int line, const std::string& what) const {
        throw InputError(file_ + ": line " + std::to_string(line) + ": " + what);
    }

    bool eof() const { return i_ >= s_.size(); }
    char peek(size_t ahead = 0) const { return i_ + ahead < s_.size() ? s_[i_ + ahead] : '\0'; }

    // The character at the current position, quoted as Python quotes it ('\r', 'é', ...).
    std::string here() const {
        if (eof()) return "the end of the file";
        std::size_t n = 1;
        const unsigned char b = static_cast<unsigned char>(peek());
        if (b >= 0xF0) n = 4;
        else if (b >= 0xE0) n = 3;
        else if (b >= 0xC0) n = 2;
        return py_repr(s_.substr(i_, n));
    }

    void skip_ws() {
        while (!eof() && (peek() == ' ' || peek() == '\t')) ++i_;
    }
    void skip_comment() {
        if (peek() != '#') return;
        while (!eof() && peek() != '\n') {
            const unsigned char c = static_cast<unsigned char>(peek());
            if (c == '\r' && peek(1) == '\n') break;
            if ((c < 0x20 && c != '\t') || c == 0x7f) fail("control character " + here() + " in a comment");
            ++i_;
        }
    }
    bool newline() {
        if (peek() == '\n') {
            ++i_;
        } else if (peek() == '\r' && peek(1) == '\n') {
            i_ += 2;
        } else {
            return false;
        }
        ++line_;
        line_start_ = i_;
        return true;
    }
    // Whitespace, comments and newlines (between statements and inside arrays).
    void skip_blank_lines() {
        for (;;) {
            skip_ws();
            skip_comment();
            if (!newline()) return;
        }
    }
    void end_of_line() {
        skip_ws();
        skip_comment();
        if (eof() || newline()) return;
        fail("unexpected " + here() + " after the value; expected the end of the line");
    }

    static bool bare_key_char(char c) {
        return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' ||
               c == '-';
    }

    std::string key() {
        if (s_.compare(i_, 3, "\"\"\"") == 0 || s_.compare(i_, 3, "'''") == 0)
            fail("a key cannot be a multi-line string");
        if (peek() == '"') return basic_string();
        if (peek() == '\'') return literal_string();
        const size_t start = i_;
        while (!eof() && bare_key_char(peek())) ++i_;
        if (i_ == start) {
            if (eof() || peek() == '\n' || peek() == '\r') fail("expected a key");
            fail("unexpected " + here() + "; expected a key");
        }
        return s_.substr(start, i_ - start);
    }

    std::vector<std::string> dotted_key() {
        std::vector<std::string> parts;
        for (;;) {
            skip_ws();
            parts.push_back(key());
            skip_ws();
            if (peek() != '.') return parts;
            ++i_;
        }
    }

    static std::string join(const std::vector<std::string>& parts, size_t n) {
        std::string out;
        for (size_t k = 0; k < n; ++k) out += (k ? "." : "") + parts[k];
        return out;
    }

    static TomlValue new_table(int line) {
        TomlValue v;
        v.kind = TomlValue::Kind::Table;
        v.line = line;
        return v;
    }

    // [a.b] or [[a.b]]: returns the table that following key/value lines fill.
    TomlValue* header(TomlValue& root) {
        const int line = line_;
        ++i_;
        const bool array = peek() == '[';
        if (array) ++i_;
        const std::vector<std::string> path = dotted_key();
        if (peek() != ']' || (array && peek(1) != ']'))
            fail(array ? "expected ']]' to close the [[table]] header" : "expected ']' to close the [table] header");
        i_ += array ? 2 : 1;

        TomlValue* t = &root;
        for (size_t k = 0; k + 1 < path.size(); ++k) {
            TomlValue* next = t->find(path[k]);
            if (!next) {
                t->entries.emplace_back(path[k], new_table(line));
                next = &t->entries.back().second;
            } else if (next->kind == TomlValue::Kind::TableArray) {
                next = &next->items.back();
            } else if (next->kind != TomlValue::Kind::Table) {
                fail_at(line, join(path, k + 1) + ": already defined as " +
                                  TomlValue::kind_name(next->kind) + " on line " +
                                  std::to_string(next->line));
            }
            if (next->frozen)
                fail_at(line, join(path, k + 1) + ": an inline table (line " + std::to_string(next->line) +
                                  ") cannot be extended");
            t = next;
        }
        const std::string& last = path.back();
        TomlValue* v = t->find(last);
        if (array) {
            if (!v) {
                TomlValue arr;
                arr.kind = TomlValue::Kind::TableArray;
                arr.line = line;
                t->entries.emplace_back(last, std::move(arr));
                v = &t->entries.back().second;
            } else if (v->kind != TomlValue::Kind::TableArray) {
                fail_at(line, join(path, path.size()) + ": already defined as " +
                                  TomlValue::kind_name(v->kind) + " on line " + std::to_string(v->line));
            }
            TomlValue table = new_table(line);
            table.defined = true;
            v->items.push_back(std::move(table));
            return &v->items.back();
        }
        if (!v) {
            TomlValue table = new_table(line);
            table.defined = true;
            t->entries.emplace_back(last, std::move(table));
            return &t->entries.back().second;
        }
        if (v->kind != TomlValue::Kind::Table || v->defined || v->frozen || v->nest_section >= 0)
            fail_at(line, "[" + join(path, path.size()) + "]: already defined on line " +
                              std::to_string(v->line));
        v->defined = true;
        v->line = line;
        return v;
    }

    // key = value, or a.b.c = value (which makes the tables a and a.b as needed).
    void key_value(TomlValue& table, bool statement) {
        const int line = line_;
        const std::vector<std::string> path = dotted_key();
        if (peek() != '=') {
            if (eof() || peek() == '\n' || peek() == '\r' || peek() == '#')
                fail("expected '=' after key '" + join(path, path.size()) + "'");
            fail("unexpected " + here() + " after key '" + join(path, path.size()) + "'; expected '='");
        }
        ++i_;
        skip_ws();
        TomlValue* t = &table;
        for (size_t k = 0; k + 1 < path.size(); ++k) {
            TomlValue* next = t->find(path[k]);
            if (!next) {
                t->entries.emplace_back(path[k], new_table(line));
                next = &t->entries.back().second;
                next->nest_section = statement ? section_ : -2;
            } else if (next->kind != TomlValue::Kind::Table || next->defined || next->frozen ||
                       (next->nest_section >= 0 && next->nest_section != section_) ||
                       (next->nest_section == -2) != !statement) {
                fail_at(line, "key '" + join(path, k + 1) + "' is already defined (line " +
                                  std::to_string(next->line) + ")");
            } else if (next->nest_section == -1) {
                next->nest_section = section_;
            }
            t = next;
        }
        if (const TomlValue* old = t->find(path.back()))
            fail_at(line, "key '" + join(path, path.size()) + "' is defined twice (first on line " +
                              std::to_string(old->line) + ")");
        TomlValue v = value();
        v.line = line;
        t->entries.emplace_back(path.back(), std::move(v));
    }

    TomlValue value() {
        TomlValue v;
        v.line = line_;
        const char c = peek();
        if (eof() || c == '\n' || c == '\r' || c == '#') fail("missing value after '='");
        if (c == '"') {
            v.kind = TomlValue::Kind::String;
            v.string = s_.compare(i_, 3, "\"\"\"") == 0 ? multiline_basic_string() : basic_string();
        } else if (c == '\'') {
            v.kind = TomlValue::Kind::String;
            v.string = s_.compare(i_, 3, "'''") == 0 ? multiline_literal_string() : literal_string();
        } else if (c == '[') {
            v.kind = TomlValue::Kind::Array;
            array(v);
        } else if (c == '{') {
            v = inline_table();
        } else if (s_.compare(i_, 4, "true") == 0 || s_.compare(i_, 5, "false") == 0) {
            fail("booleans are not supported in iwr files");
        } else {
            v.kind = TomlValue::Kind::Number;
            v.number = number();
        }
        return v;
    }

    void array(TomlValue& v) {
        ++i_;  // '['
        for (;;) {
            skip_blank_lines();
            if (eof()) fail_at(v.line, "unterminated array (no closing ']')");
            if (peek() == ']') {
                ++i_;
                return;
            }
            TomlValue item = value();
            v.items.push_back(std::move(item));
            skip_blank_lines();
            if (peek() == ',') {
                ++i_;
                continue;
            }
            if (peek() == ']') {
                ++i_;
                return;
            }
            if (eof()) fail_at(v.line, "unterminated array (no closing ']')");
            fail("unexpected " + here() + " in an array; expected ',' or ']'");
        }
    }

    // { a = 1, b.c = "x" }: on one line, no trailing comma (TOML 1.0); fixed once written.
    TomlValue inline_table() {
        TomlValue t = new_table(line_);
        t.defined = true;
        ++i_;  // '{'
        skip_ws();
        if (peek() == '}') {
            ++i_;
            t.frozen = true;
            return t;
        }
        for (;;) {
            key_value(t, false);
            skip_ws();
            if (peek() == ',') {
                ++i_;
                skip_ws();
                if (peek() == '}') fail("a trailing comma is not allowed in an inline table");
                continue;
            }
            if (peek() == '}') {
                ++i_;
                t.frozen = true;
                return t;
            }
            if (eof() || peek() == '\n' || peek() == '\r')
                fail("unterminated inline table (an inline table ends on the line it starts, with '}')");
            fail("unexpected " + here() + " in an inline table; expected ',' or '}'");
        }
    }

    static bool digit(char c) { return c >= '0' && c <= '9'; }
    static int digit_value(char c, int base) {
        int d = -1;
        if (c >= '0' && c <= '9') d = c - '0';
        else if (c >= 'a' && c <= 'f') d = c - 'a' + 10;
        else if (c >= 'A' && c <= 'F') d = c - 'A' + 10;
        return d < base ? d : -1;
    }

    // Digits with single underscores between them; appends the digits to out.
    bool digits(std::string& out) {
        if (!digit(peek())) return false;
        for (;;) {
            out += peek();
            ++i_;
            if (digit(peek())) continue;
            if (peek() == '_' && digit(peek(1))) {
                ++i_;
                continue;
            }
            return true;
        }
    }

    bool token_end() const {
        const char c = peek();
        return eof() || c == ' ' || c == '\t' || c == ',' || c == ']' || c == '}' || c == '#' || c == '\n' ||
               c == '\r';
    }

    [[noreturn]] void bad_number(size_t start) {
        size_t end = start;
        while (end < s_.size() && s_[end] != ' ' && s_[end] != '\t' && s_[end] != ',' && s_[end] != ']' &&
               s_[end] != '}' && s_[end] != '#' && s_[end] != '\n' && s_[end] != '\r')
            ++end;
        const std::string tok = s_.substr(start, end - start);
        i_ = start;
        if (tok.size() >= 8 && digit(tok[0]) && ((tok.size() > 4 && tok[4] == '-') || tok[2] == ':'))
            fail(py_repr(tok) + ": dates and times are not supported in iwr files");
        fail(py_repr(tok) + " is not a number, a string or an array");
    }

    // 0x.., 0o.., 0b..: exact, through the hexadecimal digits that strtod reads.
    double based_integer(size_t start, int base) {
        i_ += 2;
        std::string bits;  // binary digits, most significant first
        bool any = false;
        for (;;) {
            const int d = digit_value(peek(), base);
            if (d < 0) {
                if (peek() == '_' && any && digit_value(peek(1), base) >= 0) {
                    ++i_;
                    continue;
                }
                break;
            }
            any = true;
            const int width = base == 16 ? 4 : base == 8 ? 3 : 1;
            for (int b = width - 1; b >= 0; --b) bits += ((d >> b) & 1) ? '1' : '0';
            ++i_;
        }
        if (!any || !token_end()) bad_number(start);
        while (bits.size() % 4) bits.insert(bits.begin(), '0');
        std::string hex = "0x0";
        for (size_t k = 0; k < bits.size(); k += 4)
            hex += "0123456789abcdef"[std::stoi(bits.substr(k, 4), nullptr, 2)];
        return std::strtod(hex.c_str(), nullptr);  // beyond 2^1024: inf, refused as not finite
    }

    double number() {
        const size_t start = i_;
        std::string text;
        if (peek() == '0' && (peek(1) == 'x' || peek(1) == 'o' || peek(1) == 'b'))
            return based_integer(start, peek(1) == 'x' ? 16 : peek(1) == 'o' ? 8 : 2);
        if (peek() == '+' || peek() == '-') {
            text += peek();
            ++i_;
        }
        if (s_.compare(i_, 3, "inf") == 0 || s_.compare(i_, 3, "nan") == 0) {
            text += s_.substr(i_, 3);
            i_ += 3;
            if (!token_end()) bad_number(start);
        } else {
            const size_t int_start = text.size();
            if (!digits(text)) bad_number(start);
            if (text.size() - int_start > 1 && text[int_start] == '0') {
                i_ = start;
                fail(py_repr(s_.substr(start, text.size())) + ": leading zeros are not allowed");
            }
            if (peek() == '.') {
                text += '.';
                ++i_;
                if (!digits(text)) bad_number(start);
            }
            if (peek() == 'e' || peek() == 'E') {
                text += 'e';
                ++i_;
                if (peek() == '+' || peek() == '-') {
                    text += peek();
                    ++i_;
                }
                if (!digits(text)) bad_number(start);
            }
            if (!token_end()) bad_number(start);
        }
        // The C locale is in effect (the program never calls setlocale), so '.' is the separator.
        char* end = nullptr;
        const double v = std::strtod(text.c_str(), &end);
        if (end != text.c_str() + text.size()) bad_number(start);
        return v;  // overflow gives +-inf, which the robot's checks refuse as not finite
    }

    void check_string_char(bool multiline) const {
        const unsigned char c = static_cast<unsigned char>(peek());
        if (!multiline && (c == '\n' || c == '\r'))
            fail("unterminated string (a one-line string ends on the line it starts)");
        if ((c < 0x20 && c != '\t' && !(multiline && (c == '\n' || c == '\r'))) || c == 0x7f)
            fail("control character " + here() + " in a string");
        if (multiline && c == '\r' && peek(1) != '\n') fail("control character '\\r' in a string");
    }

    // One escape sequence after the backslash; appends it to out.
    void escape(std::string& out) {
        const char e = peek();
        ++i_;
        switch (e) {
            case 'b': out += '\b'; break;
            case 't': out += '\t'; break;
            case 'n': out += '\n'; break;
            case 'f': out += '\f'; break;
            case 'r': out += '\r'; break;
            case '"': out += '"'; break;
            case '\\': out += '\\'; break;
            case 'u':
            case 'U': {
                const size_t n = e == 'u' ? 4 : 8;
                unsigned long cp = 0;
                for (size_t k = 0; k < n; ++k) {
                    const int d = digit_value(peek(), 16);
                    if (d < 0) fail(std::string("bad \\") + e + " escape in a string");
                    cp = cp * 16 + static_cast<unsigned long>(d);
                    ++i_;
                }
                if (cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF))
                    fail("escape names an invalid Unicode code point");
                append_utf8(out, static_cast<char32_t>(cp));
                break;
            }
            default: {
                --i_;
                const std::string next = here();
                --i_;  // the column of the backslash
                if (e > 0x20 && e < 0x7f) fail(std::string("unknown escape '\\") + e + "' in a string");
                fail("a backslash before " + next + " in a string (an unknown escape)");
            }
        }
    }

    std::string basic_string() {
        ++i_;
        std::string out;
        for (;;) {
            if (eof()) fail("unterminated string");
            const char c = peek();
            if (c == '"') {
                ++i_;
                return out;
            }
            check_string_char(false);
            if (c != '\\') {
                out += c;
                ++i_;
                continue;
            }
            ++i_;
            escape(out);
        }
    }

    std::string literal_string() {
        ++i_;
        std::string out;
        for (;;) {
            if (eof()) fail("unterminated string");
            const char c = peek();
            if (c == '\'') {
                ++i_;
                return out;
            }
            check_string_char(false);
            out += c;
            ++i_;
        }
    }

    // """...""" and '''...''': a newline right after the opening quotes is dropped; CRLF reads as
    // LF (as tomllib); up to two quotes may stand just before the closing three.
    std::string multiline(char q) {
        const int line = line_;
        const std::string close(3, q);
        i_ += 3;
        newline();
        std::string out;
        for (;;) {
            if (eof()) fail_at(line, "unterminated multi-line string");
            if (s_.compare(i_, 3, close) == 0) {
                i_ += 3;
                for (int k = 0; k < 2 && peek() == q; ++k, ++i_) out += q;
                return out;
            }
            const char c = peek();
            if (newline()) {
                out += '\n';
                continue;
            }
            check_string_char(true);
            if (q == '"' && c == '\\') {
                // A backslash at the end of a line joins it to the next non-blank text.
                size_t k = i_ + 1;
                while (k < s_.size() && (s_[k] == ' ' || s_[k] == '\t')) ++k;
                if (k < s_.size() && (s_[k] == '\n' || (s_[k] == '\r' && k + 1 < s_.size() && s_[k + 1] == '\n'))) {
                    i_ = k;
                    for (;;) {
                        skip_ws();
                        if (!newline()) break;
                    }
                    continue;
                }
                ++i_;
                escape(out);
                continue;
            }
            out += c;
            ++i_;
        }
    }
    std::string multiline_basic_string() { return multiline('"'); }
    std::string multiline_literal_string() { return multiline('\''); }

    const std::string& s_;
    const std::string& file_;
    size_t i_ = 0;
    size_t line_start_ = 0;
    int line_ = 1;
    int section_ = 0;  // counts the [table] headers: dotted keys may only extend their own section's tables
};

}  // namespace

TomlValue parse_toml(const std::string& text, const std::string& file) {
    std::u32string decoded;
    const size_t bad = decode_utf8(text, decoded);
    if (bad != std::string::npos) throw InputError(file + ": " + utf8_error_at(text, bad) + " (TOML files are UTF-8)");
    if (!decoded.empty() && decoded[0] == 0xFEFF)
        throw InputError(file + ": line 1, column 1: the file starts with a byte order mark (U+FEFF), which "
                                "TOML does not allow; save it as UTF-8 without one");
    return Parser(text, file).parse();
}

TomlValue read_toml(const std::string& path) { return parse_toml(read_file(path, "a TOML file"), path); }

}  // namespace iwr::app

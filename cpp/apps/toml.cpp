#include "toml.hpp"

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>

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

std::string read_file(const std::string& path) {
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
                current = header(root);
            } else {
                key_value(*current);
            }
            end_of_line();
        }
        return root;
    }

private:
    [[noreturn]] void fail(const std::string& what) const { fail_at(line_, what); }
    [[noreturn]] void fail_at(int line, const std::string& what) const {
        throw InputError(file_ + ": line " + std::to_string(line) + ": " + what);
    }

    bool eof() const { return i_ >= s_.size(); }
    char peek(size_t ahead = 0) const { return i_ + ahead < s_.size() ? s_[i_ + ahead] : '\0'; }

    void skip_ws() {
        while (!eof() && (peek() == ' ' || peek() == '\t')) ++i_;
    }
    void skip_comment() {
        if (peek() != '#') return;
        while (!eof() && peek() != '\n') {
            const unsigned char c = static_cast<unsigned char>(peek());
            if ((c < 0x20 && c != '\t' && c != '\r') || c == 0x7f)
                fail("control character in a comment");
            ++i_;
        }
    }
    bool newline() {
        if (peek() == '\n') {
            ++i_;
            ++line_;
            return true;
        }
        if (peek() == '\r' && peek(1) == '\n') {
            i_ += 2;
            ++line_;
            return true;
        }
        return false;
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
        fail(std::string("unexpected '") + peek() + "' after the value; expected the end of the line");
    }

    static bool bare_key_char(char c) {
        return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' ||
               c == '-';
    }

    std::string key() {
        if (peek() == '"') return basic_string();
        if (peek() == '\'') return literal_string();
        const size_t start = i_;
        while (!eof() && bare_key_char(peek())) ++i_;
        if (i_ == start) {
            if (eof() || peek() == '\n' || peek() == '\r') fail("expected a key");
            fail(std::string("unexpected '") + peek() + "'; expected a key");
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
                TomlValue v;
                v.kind = TomlValue::Kind::Table;
                v.line = line;
                t->entries.emplace_back(path[k], std::move(v));
                next = &t->entries.back().second;
            } else if (next->kind == TomlValue::Kind::TableArray) {
                next = &next->items.back();
            } else if (next->kind != TomlValue::Kind::Table) {
                fail_at(line, join(path, k + 1) + ": already defined as " +
                                  TomlValue::kind_name(next->kind) + " on line " +
                                  std::to_string(next->line));
            }
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
            TomlValue table;
            table.kind = TomlValue::Kind::Table;
            table.line = line;
            table.defined = true;
            v->items.push_back(std::move(table));
            return &v->items.back();
        }
        if (!v) {
            TomlValue table;
            table.kind = TomlValue::Kind::Table;
            table.line = line;
            table.defined = true;
            t->entries.emplace_back(last, std::move(table));
            return &t->entries.back().second;
        }
        if (v->kind != TomlValue::Kind::Table || v->defined)
            fail_at(line, "[" + join(path, path.size()) + "]: already defined on line " +
                              std::to_string(v->line));
        v->defined = true;
        v->line = line;
        return v;
    }

    void key_value(TomlValue& table) {
        const int line = line_;
        const std::vector<std::string> path = dotted_key();
        if (path.size() > 1)
            fail("dotted key '" + join(path, path.size()) + "' is not supported; use a [table] header");
        if (peek() != '=') {
            if (eof() || peek() == '\n' || peek() == '\r' || peek() == '#')
                fail("expected '=' after key '" + path[0] + "'");
            fail(std::string("unexpected '") + peek() + "' after key '" + path[0] + "'; expected '='");
        }
        ++i_;
        skip_ws();
        if (const TomlValue* old = table.find(path[0]))
            fail_at(line, "key '" + path[0] + "' is defined twice (first on line " +
                              std::to_string(old->line) + ")");
        TomlValue v = value();
        v.line = line;
        table.entries.emplace_back(path[0], std::move(v));
    }

    TomlValue value() {
        TomlValue v;
        v.line = line_;
        const char c = peek();
        if (eof() || c == '\n' || c == '\r' || c == '#') fail("missing value after '='");
        if (c == '"') {
            v.kind = TomlValue::Kind::String;
            v.string = basic_string();
        } else if (c == '\'') {
            v.kind = TomlValue::Kind::String;
            v.string = literal_string();
        } else if (c == '[') {
            v.kind = TomlValue::Kind::Array;
            array(v);
        } else if (c == '{') {
            fail("inline tables ({...}) are not supported; use a [table] header");
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
            fail(std::string("unexpected '") + peek() + "' in an array; expected ',' or ']'");
        }
    }

    static bool digit(char c) { return c >= '0' && c <= '9'; }

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

    double number() {
        const size_t start = i_;
        std::string text;
        if (peek() == '+' || peek() == '-') {
            text += peek();
            ++i_;
        }
        auto token_end = [&] {
            const char c = peek();
            return eof() || c == ' ' || c == '\t' || c == ',' || c == ']' || c == '#' || c == '\n' ||
                   c == '\r';
        };
        auto bad = [&]() -> double {
            size_t end = start;
            while (end < s_.size() && s_[end] != ' ' && s_[end] != '\t' && s_[end] != ',' &&
                   s_[end] != ']' && s_[end] != '#' && s_[end] != '\n' && s_[end] != '\r')
                ++end;
            const std::string tok = s_.substr(start, end - start);
            if (tok.size() >= 10 && digit(tok[0]) && tok[4] == '-')
                fail("'" + tok + "': dates and times are not supported in iwr files");
            if (tok.size() > 1 && tok[0] == '0' && (tok[1] == 'x' || tok[1] == 'o' || tok[1] == 'b'))
                fail("'" + tok + "': hexadecimal, octal and binary integers are not supported");
            fail("'" + tok + "' is not a number, a string or an array");
        };
        if (s_.compare(i_, 3, "inf") == 0 || s_.compare(i_, 3, "nan") == 0) {
            text += s_.substr(i_, 3);
            i_ += 3;
            if (!token_end()) return bad();
        } else {
            const size_t int_start = text.size();
            if (!digits(text)) return bad();
            if (text.size() - int_start > 1 && text[int_start] == '0')
                fail("'" + s_.substr(start, i_ - start) + "': leading zeros are not allowed");
            if (peek() == '.') {
                text += '.';
                ++i_;
                if (!digits(text)) return bad();
            }
            if (peek() == 'e' || peek() == 'E') {
                text += 'e';
                ++i_;
                if (peek() == '+' || peek() == '-') {
                    text += peek();
                    ++i_;
                }
                if (!digits(text)) return bad();
            }
            if (!token_end()) return bad();
        }
        // The C locale is in effect (the program never calls setlocale), so '.' is the separator.
        errno = 0;
        char* end = nullptr;
        const double v = std::strtod(text.c_str(), &end);
        if (end != text.c_str() + text.size()) return bad();
        return v;  // overflow gives +-inf, which the robot's checks refuse as not finite
    }

    static void append_utf8(std::string& out, unsigned long cp) {
        if (cp < 0x80) {
            out += static_cast<char>(cp);
        } else if (cp < 0x800) {
            out += static_cast<char>(0xC0 | (cp >> 6));
            out += static_cast<char>(0x80 | (cp & 0x3F));
        } else if (cp < 0x10000) {
            out += static_cast<char>(0xE0 | (cp >> 12));
            out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
            out += static_cast<char>(0x80 | (cp & 0x3F));
        } else {
            out += static_cast<char>(0xF0 | (cp >> 18));
            out += static_cast<char>(0x80 | ((cp >> 12) & 0x3F));
            out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
            out += static_cast<char>(0x80 | (cp & 0x3F));
        }
    }

    void check_string_char(char ch) const {
        const unsigned char c = static_cast<unsigned char>(ch);
        if (c == '\n' || c == '\r') fail("unterminated string (strings end on the line they start)");
        if ((c < 0x20 && c != '\t') || c == 0x7f) fail("control character in a string");
    }

    std::string basic_string() {
        if (s_.compare(i_, 3, "\"\"\"") == 0) fail("multi-line strings are not supported");
        ++i_;
        std::string out;
        for (;;) {
            if (eof()) fail("unterminated string");
            const char c = peek();
            if (c == '"') {
                ++i_;
                return out;
            }
            check_string_char(c);
            if (c != '\\') {
                out += c;
                ++i_;
                continue;
            }
            ++i_;
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
                        const char h = peek();
                        int d;
                        if (h >= '0' && h <= '9') d = h - '0';
                        else if (h >= 'a' && h <= 'f') d = h - 'a' + 10;
                        else if (h >= 'A' && h <= 'F') d = h - 'A' + 10;
                        else fail(std::string("bad \\") + e + " escape in a string");
                        cp = cp * 16 + static_cast<unsigned long>(d);
                        ++i_;
                    }
                    if (cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF))
                        fail("escape names an invalid Unicode code point");
                    append_utf8(out, cp);
                    break;
                }
                default:
                    fail(std::string("unknown escape '\\") + e + "' in a string");
            }
        }
    }

    std::string literal_string() {
        if (s_.compare(i_, 3, "'''") == 0) fail("multi-line strings are not supported");
        ++i_;
        std::string out;
        for (;;) {
            if (eof()) fail("unterminated string");
            const char c = peek();
            if (c == '\'') {
                ++i_;
                return out;
            }
            check_string_char(c);
            out += c;
            ++i_;
        }
    }

    const std::string& s_;
    const std::string& file_;
    size_t i_ = 0;
    int line_ = 1;
};

}  // namespace

TomlValue parse_toml(const std::string& text, const std::string& file) {
    if (text.size() >= 3 && text.compare(0, 3, "\xEF\xBB\xBF") == 0)
        return Parser(text.substr(3), file).parse();
    return Parser(text, file).parse();
}

TomlValue read_toml(const std::string& path) { return parse_toml(read_file(path), path); }

}  // namespace iwr::app

// A strict TOML 1.0 reader for the robot files, accepting what Python's tomllib accepts there:
// [tables], [[arrays of tables]], dotted keys, inline tables, numbers (decimal, hexadecimal,
// octal and binary integers, floats, inf and nan), the four kinds of strings, arrays (nested,
// multi-line, trailing comma) and comments, in UTF-8 without a byte order mark. Booleans and
// dates, which no key of a robot file takes, are refused at once. Every error names the file and
// line (and column, for a syntax error), never guessed at.
#pragma once

#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace iwr::app {

/// A malformed or unsupported input file; what() is "FILE: line N: problem" (or "FILE: problem").
class InputError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

struct TomlValue {
    enum class Kind { Number, String, Array, Table, TableArray };
    Kind kind = Kind::Table;
    int line = 0;                // where the value (or the table's header) was written
    double number = 0;
    std::string string;
    std::vector<TomlValue> items;  // Array and TableArray (whose items are Tables)
    std::vector<std::pair<std::string, TomlValue>> entries;  // Table, in file order
    bool defined = false;        // a Table given its own [header] (or the root), or inline
    bool frozen = false;         // an inline table: nothing may be added to it later
    int nest_section = -1;       // a Table made by dotted keys: in which [section] (-2: inline)

    const TomlValue* find(const std::string& key) const;
    TomlValue* find(const std::string& key);
    static const char* kind_name(Kind k);
};

/// Parses `text` (the contents of `file`, used in messages). Throws InputError.
TomlValue parse_toml(const std::string& text, const std::string& file);

/// Reads and parses a file. Throws InputError ("FILE: no such file", ...).
TomlValue read_toml(const std::string& path);

/// Reads a whole file as bytes. Throws InputError naming the file ("FILE: no such file", "FILE: is
/// a folder, not KIND", ...).
std::string read_file(const std::string& path, const char* kind = "a file");

}  // namespace iwr::app

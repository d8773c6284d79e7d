// A strict reader for the subset of TOML that iwr writes (iwr.Robot.to_toml, through tomli-w):
// [tables], [[arrays of tables]], key = value with numbers (integers and floats, inf and nan
// included), basic and literal one-line strings, arrays (nested, multi-line, trailing comma),
// and comments. Everything else (booleans, dates, inline tables, multi-line strings, dotted keys
// on the left of '=') is refused with an error naming the file and line, never guessed at.
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
    bool defined = false;        // a Table given its own [header] (or the root)

    const TomlValue* find(const std::string& key) const;
    TomlValue* find(const std::string& key);
    static const char* kind_name(Kind k);
};

/// Parses `text` (the contents of `file`, used in messages). Throws InputError.
TomlValue parse_toml(const std::string& text, const std::string& file);

/// Reads and parses a file. Throws InputError ("FILE: no such file", ...).
TomlValue read_toml(const std::string& path);

/// Reads a whole file as bytes. Throws InputError naming the file.
std::string read_file(const std::string& path);

}  // namespace iwr::app

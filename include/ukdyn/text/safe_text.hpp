// Text that leaves ukdyn for a terminal, a generated script or a file name, made safe for it.
#pragma once

#include <string>
#include <string_view>

namespace ukdyn {

/// For a terminal or a log: control bytes (C0, DEL, the UTF-8 encoded C1 controls U+0080–U+009F)
/// and bytes that are not valid UTF-8 are written as \xNN. A backslash stays as it is: the loader's
/// messages already show the control bytes of a name as \xNN, and escaping again would print
/// \\xNN (names never hold a backslash: the identifier rule). With keep_newlines, '\n' stays
/// (multi-line messages); otherwise it is escaped too.
std::string printable(std::string_view text, bool keep_newlines = false);

/// The narrower escape of the scenario loader's messages (ScenarioError, the sweep file's errors):
/// only the C0 control bytes ('\n' among them) and DEL are written as \xNN; every other byte stays
/// as it is (UTF-8 is not checked: a C1 control or a byte that is not UTF-8 passes). It is the same
/// escape as printable() with fewer bytes escaped, and what reaches a terminal still goes through
/// printable() (the CLI prints every error that way): printable(escape_controls(s), true) ==
/// printable(s) for every s.
std::string escape_controls(std::string_view text);

/// A gnuplot string literal that holds exactly `text` and nothing else: double-quoted, with '"' and
/// '\' backslash-escaped and every control byte, backquote, '@' and single quote written as an
/// octal escape \ooo. So the literal holds no raw byte that could end the command line (a newline,
/// a carriage return), start a command substitution (`...`) or a macro (@name). (Single quotes are
/// not used: gnuplot 5.4 misparses a doubled quote at the start of a single-quoted string.)
std::string gnuplot_string(std::string_view text);

/// A file-name stem from a name: letters, digits, '_', '-' and '.' kept, every other byte '_',
/// no leading '.', at most 64 bytes; never empty.
std::string file_stem(std::string_view name);

/// A CSV field (RFC 4180): quoted, with quotes doubled, if it holds ',', '"', CR or LF.
std::string csv_field(std::string_view text);

}  // namespace ukdyn

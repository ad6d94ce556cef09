#pragma once
// Expected<T>: a value or an Error with a human-readable message. Bad input of
// any kind (files, frames, fields, flags) is reported through this type; it
// never throws and never aborts. (std::expected arrives with C++23.)

#include <cassert>
#include <string>
#include <utility>
#include <variant>

namespace penumbra {

/// A failure described for a human: names the thing (file, field, peer) and
/// the problem, e.g. "scenes/x.obj: line 12: face index 40 out of range".
struct Error {
  std::string message;
  /// Trying the same thing again gives the same answer (e.g. a server
  /// certificate our CA refuses): an interactive caller stops and says so,
  /// where a transient failure (refused, timed out) is worth a retry.
  bool permanent = false;
};

/// Builds an Error; lets callers write `return Fail("...")` in any Expected.
inline Error Fail(std::string message) { return Error{std::move(message)}; }

/// Holds either a T or an Error. Access to the wrong alternative is a
/// programming error (asserted), so check `ok()` / `operator bool` first.
template <class T>
class [[nodiscard]] Expected {
 public:
  Expected(T value) : v_(std::in_place_index<0>, std::move(value)) {}  // NOLINT
  Expected(Error error) : v_(std::in_place_index<1>, std::move(error)) {}  // NOLINT

  bool ok() const { return v_.index() == 0; }
  explicit operator bool() const { return ok(); }

  T& value() & { assert(ok()); return std::get<0>(v_); }
  const T& value() const& { assert(ok()); return std::get<0>(v_); }
  T&& value() && { assert(ok()); return std::get<0>(std::move(v_)); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }

  const Error& error() const { assert(!ok()); return std::get<1>(v_); }

 private:
  std::variant<T, Error> v_;
};

/// Success or an Error, for operations without a result value.
class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(Error error) : error_(std::move(error)), ok_(false) {}  // NOLINT
  static Status Ok() { return Status(); }

  bool ok() const { return ok_; }
  explicit operator bool() const { return ok_; }
  const Error& error() const { assert(!ok_); return error_; }

 private:
  Error error_;
  bool ok_ = true;
};

}  // namespace penumbra

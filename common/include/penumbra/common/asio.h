#pragma once
// Include Boost.Asio only through this header: Boost 1.74's asio uses
// std::exchange without including <utility>, which GCC 12 in C++20 mode
// rejects.
#include <utility>  // must precede every asio header

#include <boost/asio.hpp>

namespace penumbra {
namespace asio = boost::asio;
using tcp = boost::asio::ip::tcp;
}  // namespace penumbra

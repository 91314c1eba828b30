"""Network addresses as a user writes them (a viewer's URL, a bind address, a Dask
scheduler): syntax only, nothing is resolved or asked."""

from __future__ import annotations

import ipaddress
import re

__all__ = ["host_ok", "hostname_ok"]


def hostname_ok(host: str) -> bool:
    """A host name of DNS syntax (labels of 1 to 63 letters, digits and hyphens; at most
    253 bytes), not all digits (an IPv4 address is checked as one)."""
    if not host or len(host) > 253 or re.fullmatch(r"[0-9.]+", host):
        return False
    return all(re.fullmatch(r"(?!-)[A-Za-z0-9_-]{1,63}(?<!-)", part) for part in host.rstrip(".").split("."))


def host_ok(host: str) -> bool:
    """An IP address (v4, or v6 in brackets or not) or a host name of DNS syntax."""
    try:
        ipaddress.ip_address(host.strip("[]"))
        return True
    except ValueError:
        return hostname_ok(host)

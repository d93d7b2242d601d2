"""A read-only browser dashboard of a store: runs, CMRTs, clips (``cmrt dashboard``; docs/howto/dashboard.md)."""

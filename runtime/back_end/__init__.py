"""The back end (global SLAM): the loop search and its verification, the wide search, Gauss–Newton
on the pose graph and its sparse factorisation (docs/method.md §5, docs/runtime.md §3)."""

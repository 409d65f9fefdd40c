import os

os.environ.setdefault("MPLBACKEND", "Agg")


def pytest_collection_modifyitems(items):
    """schemathesis gives the tests it makes of one function (one per API operation) that function's nodeid
    (the operation is in the name only): each gets its own, parent::name, so reports name the operation and
    xdist's --dist loadscope (which keys tests by nodeid) runs every one of them."""
    for item in items:
        if getattr(item, "operation_label", None) is not None and item.nodeid != f"{item.parent.nodeid}::{item.name}":
            item._id = item.parent.id.child(item.name)

"""Wire models shared by the service and the client (pydantic v2; numpy + pydantic only)."""

from drape.schemas.catalog import BodyInfo, BodyList, Health, MotionInfo, MotionList

__all__ = ["BodyInfo", "BodyList", "Health", "MotionInfo", "MotionList"]

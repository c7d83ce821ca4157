"""Plant: CPlantBox growth, segment table, mesh and field geometry."""

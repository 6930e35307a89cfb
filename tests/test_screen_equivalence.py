

@pytest.mark.parametrize("name", ["025_mug", "box beside the mug", "grid box"])
def test_volumes_counted_only_where_the_table_is_clear_give_the_verdicts_of_counting_every_pose(ycb_clouds, name):
    screened = screen_candidates([ycb_clouds[name]], CONFIG, [2])
    rows = torch.arange(0, screened.width_m.shape[0], 3)
    geometry = gripper_geometry(CONFIG.planner)
    counted = gripper_occupancy(screened.occupancy_points, screened.object_index[rows], screened.centre_world[rows], screened.rotation_world[rows],
                                screened.width_m[rows], geometry, 10**9)
    under_limit = counted.total.to(torch.float32) <= CONFIG.planner.occupancy_max_fraction * screened.occupancy_total[0]
    expected = screened.clear_of_table[rows] & under_limit
    assert torch.equal(screened.table_and_volume_ok(rows), expected)
    assert expected.any() and not expected.all() and (screened.clear_of_table[rows] & ~under_limit).any()
